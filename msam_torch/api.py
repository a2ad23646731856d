"""The Python entry point: ``adapt(config)`` runs MSAM on every state equation of a config."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import torch

from .candidates import EquationData
from .config import Config, load_config
from .data import load_datasets
from .result import EquationResult, RunResult, format_component, format_equation
from .spec import Equation, ModelSpec
from .step import StepOptions
from .systems import perturb_parameters
from .trainer import Fit, Trainer


def step_options(config: Config) -> StepOptions:
    a = config.adaptation
    return StepOptions(dgamma=a.dgamma, scaling=a.scaling, step_size=a.step_size, theta=a.theta,
                       damping=a.damping, gamma_limit=a.gamma_limit)


def make_trainer(config: Config) -> Trainer:
    a = config.adaptation
    return Trainer(step_options(config), a.round_robin_steps, a.refinement_steps, a.chunk_size)


def nominal_parameters(config: Config, spec: ModelSpec) -> dict:
    """The model's parameters with the configured parametric error drawn from ``data.seed``."""
    generator = torch.Generator().manual_seed(config.data.seed)
    return perturb_parameters(spec.parameters, config.data.parametric_error, generator)


def adapt(config: Config | dict | str, overrides: list[str] = (),
          on_trainer: Callable[[Trainer, Equation], None] | None = None, base_dir: str | Path | None = None) -> RunResult:
    """Run Algorithm 1 on each state equation; ``on_trainer`` may attach callbacks.

    Data file paths are relative to ``base_dir`` (default: the config file's folder)."""
    if base_dir is None:
        base_dir = Path(config).parent if isinstance(config, (str, Path)) else Path(".")
    if not isinstance(config, Config):
        config = load_config(config, overrides)
    spec = ModelSpec.from_config(config.model)
    if config.adaptation.evaluation == "simulation":
        from .simulation_mode import adapt_simulation

        return adapt_simulation(config, spec, nominal_parameters(config, spec), Path(base_dir), on_trainer)
    dtype = getattr(torch, config.adaptation.dtype)
    device = torch.device(config.adaptation.device)
    train, validation = load_datasets(config.data, spec, base_dir, dtype=dtype)
    signals = {k: v.to(device) for k, v in train.signals.items()}
    provenance = train.info
    parameters = nominal_parameters(config, spec)
    results = []
    for equation in spec.equations:
        data = EquationData.build(equation, signals, config.adaptation.normalize)
        theta = spec.theta(equation, parameters).to(device=device, dtype=dtype)
        trainer = make_trainer(config)
        if on_trainer is not None:
            on_trainer(trainer, equation)
        start = torch.tensor([equation.components[i].start for i in equation.adjustable], dtype=dtype, device=device)
        fit = trainer.fit(data, theta[list(equation.adjustable)].unsqueeze(0), theta[list(equation.fixed)].unsqueeze(0), start)
        results.append(equation_result(equation, fit, theta, data.scale[0]))
    provenance = {**provenance, "nominal_parameters": parameters}
    return RunResult(results, config.model_dump(mode="json"), provenance)


def candidate_label(equation: Equation, choice) -> list[str]:
    return [equation.adjustments[int(f)].text for f in choice]


def equation_result(equation: Equation, fit: Fit, theta: torch.Tensor, scale: torch.Tensor, trial: int = 0) -> EquationResult:
    """One trial of a :class:`Fit` as an :class:`EquationResult`.

    With normalised adjustment functions (``f / s``) the printed theta absorbs ``s^-gamma`` so
    the equation reads in the data's own units.
    """
    winner = int(fit.winner[trial])
    choice = fit.choices[winner].tolist()
    gamma = fit.gamma[trial].tolist()
    adjusted_theta = fit.theta[trial] * scale[fit.choices[winner]] ** (-fit.gamma[trial])
    thetas, terms, adjustments, exponents = [], [], [], []
    slot = {i: k for k, i in enumerate(equation.adjustable)}
    fixed_slot = {i: k for k, i in enumerate(equation.fixed)}
    for i, _ in enumerate(equation.components):
        if i in slot:
            k = slot[i]
            thetas.append(float(adjusted_theta[k]))
            terms.append(format_component(equation, i, choice[k], gamma[k]))
            adjustments.append(equation.adjustments[choice[k]].text)
            exponents.append(gamma[k])
        else:
            thetas.append(float(fit.theta_fixed[trial, fixed_slot[i]]))
            terms.append(format_component(equation, i, None, None))
            adjustments.append(None)
            exponents.append(None)
    order = torch.argsort(fit.ranking_fitness[trial], descending=True).tolist()
    ranking = [{"candidate": c, "adjustments": candidate_label(equation, fit.choices[c]),
                "fitness": float(fit.ranking_fitness[trial, c]),
                "exponents": fit.ranking_gamma[trial, c].tolist(),
                "diverged": bool(fit.diverged[trial, c])} for c in order]
    pick = lambda d: {k: float(v[trial]) for k, v in d.items()}
    start_terms = [c.term.text for c in equation.components]
    return EquationResult(
        target=equation.target,
        equation=format_equation(equation.target, thetas, terms),
        start_equation=format_equation(equation.target, theta.tolist(), start_terms),
        adjustments=adjustments, exponents=exponents, theta=thetas,
        start=pick(fit.start), final=pick(fit.final), ranking=ranking,
        diverged=int(fit.diverged[trial].sum()),
    )
