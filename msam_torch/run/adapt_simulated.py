"""Algorithm 1 with simulation-based evaluation from a config: the records, the theta-retuned
starting model (a short Levenberg-Marquardt fit of theta and the initial states of the unadjusted
model), ``normalize: rms`` along that starting simulation, the round robin and refinement on every
group of equations, and the results with free-run checks on the training and validation records."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import torch

from msam_torch.data.loading import Dataset
from msam_torch.engine.trainer import Trainer
from msam_torch.engine.values import simulates
from msam_torch.errors import ConfigError
from msam_torch.model.notation import format_component, format_equation
from msam_torch.model.spec import Equation
from msam_torch.run.plan import Plan
from msam_torch.run.result import EquationResult, RunResult
from msam_torch.simulation.configured import load_records, output_states, state_limits
from msam_torch.simulation.free_run import free_run, rmse
from msam_torch.simulation.least_squares import fit_parameters
from msam_torch.simulation.ode import Parameters, build_model, groups
from msam_torch.simulation.problem import SimulationData, unpacked
from msam_torch.simulation.record import Record
from msam_torch.simulation.solver import simulate


def function_scale(data: SimulationData, choice, gamma, theta, theta_fixed, initial) -> torch.Tensor:
    """RMS of every adjustment function along a simulation (T, G) (``normalize: rms``)."""
    p = Parameters(gamma, choice, theta, theta_fixed, torch.ones_like(data.scale))
    states = simulate(data.model, data.record, p, initial, data.method, data.substeps, data.limits)  # (T, N, S)
    external = data.record.external.unsqueeze(0).expand(states.shape[:-1] + data.record.external.shape[-1:])
    values = data.model.values(data.record.t.view(1, -1).expand(states.shape[:-1]), states, external)
    f = data.model.functions_at(values, states.shape[:-1])
    return torch.sqrt((f * f).mean(-2)).clamp_min(torch.finfo(f.dtype).tiny)


@dataclass(frozen=True)
class Prepared:
    """A group ready for Algorithm 1: the data (with fitted initial states and function scale) and
    the theta-retuned starting model's theta (T, Qa), (T, P)."""

    data: SimulationData
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    validation: Record | None


def prepare_group(plan: Plan, group: tuple[Equation, ...], parameters: dict | list[dict], base_dir: Path, data=None,
            validation=None) -> Prepared:
    """Records (from the config, or ``data`` and ``validation``), the starting model's fit of theta
    and initial states, and the function scale; a list of parameter sets gives one trial each."""
    config, spec, dtype, device = plan.config, plan.spec, plan.dtype, plan.device
    model = build_model(spec, group)
    outputs = output_states(config, spec, model)
    train, held_out = load_records(config, spec, model, outputs, base_dir, dtype, data, validation, plan.derivatives)
    train, held_out = train.to(device), None if held_out is None else held_out.to(device)
    a, sim = config.adaptation, config.adaptation.simulation
    trials = parameters if isinstance(parameters, list) else [parameters]
    thetas = [[spec.theta(eq, values).to(device=device, dtype=dtype) for eq in group] for values in trials]
    theta = torch.stack([torch.stack([th[e][i] for e, i in model.adjustable]) for th in thetas])
    theta_fixed = torch.stack([torch.stack([th[e][i] for e, i in model.fixed]) for th in thetas]) if model.fixed \
        else theta.new_zeros(len(trials), 0)
    t, q, p, s = theta.shape[0], theta.shape[-1], theta_fixed.shape[-1], len(model.states)
    free = torch.tensor([plan.options.theta.re_solved] * (q + p) + [sim.initial == "estimate"] * s, device=device)
    problem = SimulationData(model, train, tuple(model.states.index(o) for o in outputs), train.guess.expand(t, -1),
                             torch.ones(t, len(model.functions), dtype=dtype, device=device), free, sim.method,
                             sim.substeps, sim.refit_steps, state_limits(config, model.states, dtype, device))
    unadjusted = torch.full((t, 1, q), model.unadjusted, dtype=torch.long, device=device)
    gamma = theta.new_zeros(t, 1, q)
    z = torch.cat([theta, theta_fixed, problem.initial], -1).unsqueeze(1)
    z, _ = fit_parameters(problem, unadjusted, gamma, z, free, sim.prefit_steps)
    theta, theta_fixed, initial = (v[:, 0] for v in unpacked(z, q, p))
    problem = replace(problem, initial=initial)
    if a.normalize == "rms":
        problem = replace(problem, scale=function_scale(problem, unadjusted[:, 0], gamma[:, 0], theta, theta_fixed, initial))
    return Prepared(problem, theta, theta_fixed, held_out)


def simulation_trainer(plan: Plan, factory: Callable[[Plan], Trainer]) -> Trainer:
    """The trainer of ``factory`` judging candidates by simulation."""
    trainer = factory(plan)
    if not isinstance(trainer, Trainer):
        raise ConfigError("trainer_factory", f"simulation-based evaluation needs a Trainer, got {type(trainer).__name__}")
    if not simulates(trainer.evaluator):  # the factory's default evaluator
        trainer.evaluator = plan.evaluator
    return trainer


def adapt_simulation(plan: Plan, parameters: dict, base_dir: Path, trainer_factory: Callable[[Plan], Trainer],
                     on_trainer=None, data=None, validation=None) -> RunResult:
    """Algorithm 1 with simulation-based evaluation on every group of equations -> RunResult.

    ``RunResult.data['simulation']`` holds, per group: the outputs, the fitted initial states and
    the free-run RMSE of the theta-retuned starting model and of the adapted model on the training
    and (if any) validation records (initial states fitted on each record).
    """
    config, spec, dtype, device = plan.config, plan.spec, plan.dtype, plan.device
    results, reports = [], []
    for group in groups(spec, config.adaptation.simulation.coupling):
        prepared = prepare_group(plan, group, parameters, base_dir, data, validation)
        model = prepared.data.model
        trainer = simulation_trainer(plan, trainer_factory)
        if on_trainer is not None:
            on_trainer(trainer, label_equation(model))
        start = torch.tensor([group[e].components[i].start for e, i in model.adjustable], dtype=dtype, device=device)
        fit = trainer.fit(prepared.data, prepared.theta, prepared.theta_fixed, start, choices=model.choices(device))
        results.extend(equation_results(fit, prepared))
        reports.append(report(prepared, fit))
    source = config.data.file or f"system:{config.data.system}" if data is None else \
        str(data) if isinstance(data, (str, Path)) else data.info.get("source", "dataset") if isinstance(data, Dataset) \
        else "data frame"
    return RunResult(results, config.model_dump(mode="json"),
                     {"source": source, "evaluation": "simulation", "nominal_parameters": parameters,
                      "simulation": reports})


def label_equation(model) -> Equation:
    """A stand-in equation naming the group for callbacks: its adjustments are the group's
    functions, so ``candidate_label`` reads joint candidates."""
    return Equation(",".join(eq.target for eq in model.equations), (), model.functions)


def report(prepared: Prepared, fit) -> dict:
    """Fitted initial states, the theta-retuned starting model's theta per equation (data units) and
    free-run RMSE (retuned start vs adapted) on training and validation."""
    data, model = prepared.data, prepared.data.model
    unadjusted = torch.full_like(fit.choices[:1].expand(fit.gamma.shape[0], -1), model.unadjusted)
    chosen = fit.choices[fit.winner]
    rows = {"start": (unadjusted, torch.zeros_like(fit.gamma), prepared.theta, prepared.theta_fixed),
            "adapted": (chosen, fit.gamma, fit.theta, fit.theta_fixed)}
    retuned = {eq.target: [0.0] * len(eq.components) for eq in model.equations}
    for slots, values in ((model.adjustable, prepared.theta), (model.fixed, prepared.theta_fixed)):
        for k, (e, i) in enumerate(slots):
            retuned[model.equations[e].target][i] = float(values[0, k])
    out = {"outputs": [model.states[i] for i in data.outputs],
           "initial": dict(zip(model.states, (fit.initial if fit.initial is not None else data.initial)[0].tolist())),
           "retuned_theta": retuned, "free_run_rmse": {}}
    both = [torch.cat([r[k] for r in rows.values()]) for k in range(4)]  # start and adapted as two rows
    scale = data.scale.expand(len(rows), -1)
    for name, record in (("train", data.record), ("validation", prepared.validation)):
        if record is not None:
            simulated, _ = free_run(replace(data, scale=scale), record, *both, steps=3)
            out["free_run_rmse"][name] = {label: rmse(record, simulated[k]) for k, label in enumerate(rows)}
    return out


def equation_results(fit, prepared: Prepared, trial: int = 0) -> list[EquationResult]:
    """One :class:`EquationResult` per equation of the group (measures and ranking are the group's)."""
    model = prepared.data.model
    winner = int(fit.winner[trial])
    choice = fit.choices[winner]
    scale = prepared.data.scale[trial]
    gamma = fit.gamma[trial]
    theta = fit.theta[trial] * scale[choice] ** (-gamma)
    labels = lambda c: [model.functions[int(f)].text for f in c]
    order = torch.argsort(fit.ranking_fitness[trial], descending=True).tolist()
    ranking = [{"candidate": c, "adjustments": labels(fit.choices[c]), "fitness": float(fit.ranking_fitness[trial, c]),
                "exponents": fit.ranking_gamma[trial, c].tolist(), "diverged": bool(fit.diverged[trial, c])}
               for c in order]
    pick = lambda d: {k: float(v[trial]) for k, v in d.items()}
    results = []
    for e, eq in enumerate(model.equations):
        thetas, terms, adjustments, exponents, start_thetas = [], [], [], [], []
        for i, component in enumerate(eq.components):
            if (e, i) in model.adjustable:
                k = model.adjustable.index((e, i))
                function = int(choice[k])
                local = [f.text for f in eq.adjustments].index(model.functions[function].text)
                thetas.append(float(theta[k]))
                start_thetas.append(float(prepared.theta[trial, k]))
                terms.append(format_component(eq, i, local, float(gamma[k])))
                adjustments.append(model.functions[function].text)
                exponents.append(float(gamma[k]))
            else:
                k = model.fixed.index((e, i))
                thetas.append(float(fit.theta_fixed[trial, k]))
                start_thetas.append(float(prepared.theta_fixed[trial, k]))
                terms.append(format_component(eq, i, None, None))
                adjustments.append(None)
                exponents.append(None)
        results.append(EquationResult(
            target=eq.target, equation=format_equation(eq.target, thetas, terms),
            start_equation=format_equation(eq.target, start_thetas, [c.term.text for c in eq.components]),
            adjustments=adjustments, exponents=exponents, theta=thetas, start=pick(fit.start), adapted=pick(fit.adapted),
            ranking=ranking, diverged=int(fit.diverged[trial].sum())))
    return results
