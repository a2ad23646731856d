"""Free runs: models simulated under the measured inputs with only their initial states fitted to
the record's outputs (the held-out check of a simulation-based adaptation and of the diagnosis)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import torch

from msam_torch.config.schema import Config
from msam_torch.model.spec import ModelSpec
from msam_torch.simulation.configured import load_records, output_states, state_limits
from msam_torch.simulation.least_squares import fit_parameters
from msam_torch.simulation.ode import Parameters, SystemModel, build_model
from msam_torch.simulation.problem import SimulationData
from msam_torch.simulation.record import Record
from msam_torch.simulation.solver import simulate


def free_run(data: SimulationData, record: Record, choice, gamma, theta, theta_fixed, steps: int = 6,
             estimate_initial: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """Simulate a model (T rows of choice, gamma, theta) on ``record``; only its initial states are
    fitted (by least squares on the record's outputs). Returns outputs (T, O, N) and initial states."""
    on_record = replace(data, record=record, initial=record.guess.expand(theta.shape[0], -1))
    q, p, s = theta.shape[-1], theta_fixed.shape[-1], record.guess.shape[-1]
    free = torch.tensor([False] * (q + p) + [estimate_initial] * s, device=theta.device)
    z = torch.cat([theta, theta_fixed, on_record.initial], -1).unsqueeze(1)
    z, out = fit_parameters(replace(on_record, free=free), choice.unsqueeze(1), gamma.unsqueeze(1), z, free, steps)
    return out[:, 0].unflatten(-1, (record.outputs.shape[0], -1)), z[:, 0, q + p:]


def rmse(record: Record, simulated: torch.Tensor) -> list[float]:
    """Root-mean-square error of each output (O,) for one simulated row (O, N)."""
    return torch.sqrt(((record.outputs - simulated) ** 2).mean(-1)).tolist()


@dataclass(frozen=True)
class FreeRun:
    """Free runs of B models on one record: the record, the output names and the simulated states
    (B, N, S) of ``model`` (initial states fitted on the record's outputs)."""

    record: Record
    model: SystemModel
    outputs: tuple[str, ...]
    states: torch.Tensor

    @property
    def simulated(self) -> torch.Tensor:
        """Simulated outputs (B, O, N)."""
        return self.states[..., [self.model.states.index(o) for o in self.outputs]].movedim(-1, -2)


def free_runs(config: Config, spec: ModelSpec, models: dict[str, list], base_dir: Path | str,
              records: tuple[str, ...] = ("train", "validation"), steps: int = 6, dtype=torch.float64,
              data=None, validation=None) -> dict[str, FreeRun]:
    """Every model of ``spec`` run jointly (all equations) under the measured inputs of each of
    ``records`` (those configured or given as ``data``, ``validation``), with only its initial
    states fitted (``steps`` Levenberg-Marquardt steps). ``models`` maps a label to one entry per
    equation with ``adjustments`` (per component: the adjustment text, or None for an unadjusted
    or fixed component), ``exponents`` and ``theta`` in the data's units, e.g.
    :class:`~msam_torch.run.result.EquationResult`."""
    model = build_model(spec, spec.equations)
    outputs = output_states(config, spec, model)
    train, held_out = load_records(config, spec, model, outputs, Path(base_dir), dtype, data, validation)
    texts = [f.text for f in model.functions]
    rows = []
    for entries in models.values():
        choice, gamma, theta = [], [], []
        for e, i in model.adjustable:
            entry = entries[e]
            text = entry.adjustments[i]
            choice.append(model.unadjusted if text is None else texts.index(text))
            gamma.append(0.0 if entry.exponents[i] is None else float(entry.exponents[i]))
            theta.append(float(entry.theta[i]))
        rows.append((choice, gamma, theta, [float(entries[e].theta[i]) for e, i in model.fixed]))
    as_tensor = lambda k, kind=dtype: torch.tensor([r[k] for r in rows], dtype=kind).reshape(len(rows), -1)
    choice, gamma, theta, theta_fixed = as_tensor(0, torch.long), as_tensor(1), as_tensor(2), as_tensor(3)
    sim = config.adaptation.simulation
    scale = torch.ones(len(rows), len(model.functions), dtype=dtype)
    problem = SimulationData(model, train, tuple(model.states.index(o) for o in outputs), train.guess.unsqueeze(0),
                             scale, torch.zeros(theta.shape[-1] + theta_fixed.shape[-1] + len(model.states), dtype=torch.bool),
                             sim.method, sim.substeps, limits=state_limits(config, model.states, dtype))
    out = {}
    for name, record in (("train", train), ("validation", held_out)):
        if record is not None and name in records:
            _, initial = free_run(problem, record, choice, gamma, theta, theta_fixed, steps,
                                  estimate_initial=sim.initial == "estimate")
            states = simulate(model, record, Parameters(gamma, choice, theta, theta_fixed, scale), initial,
                              sim.method, sim.substeps, problem.limits)
            if problem.limits is not None:
                states = torch.clamp(states, problem.limits[0], problem.limits[1])
            out[name] = FreeRun(record, model, outputs, states)
    return out


def free_run_models(config: Config, spec: ModelSpec, models: dict[str, list], base_dir: Path | str,
                    records: tuple[str, ...] = ("train", "validation"), steps: int = 6, dtype=torch.float64,
                    data=None, validation=None) -> dict:
    """Free-run RMSE of several models (see :func:`free_runs`) on the training and validation
    records: ``{"outputs": [...], "free_run_rmse": {record: {label: [rmse per output]}},
    "simulated": {record: {label: (O, N) list}}}``."""
    runs = free_runs(config, spec, models, base_dir, records, steps, dtype, data, validation)
    out = {"outputs": list(output_states(config, spec, build_model(spec, spec.equations))), "free_run_rmse": {},
           "simulated": {}}
    for name, run in runs.items():
        simulated = run.simulated
        out["free_run_rmse"][name] = {label: rmse(run.record, simulated[k]) for k, label in enumerate(models)}
        out["simulated"][name] = {label: simulated[k].tolist() for k, label in enumerate(models)}
    return out
