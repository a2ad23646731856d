"""Batched trials: many draws of the nominal parameters adapted in one tensor program.

The controlled tests of the paper (Tables 2-4, Figure 5) repeat Algorithm 1 on the same data with
nominal parameters drawn at a parametric error level (docs/design.md 2.8). The trials only differ in
their nominal theta, so they share the data (expanded, not copied, along the leading trials axis
T of :class:`~msam_torch.engine.candidates.EquationData`) and run together. Trials, then candidates, are
chunked so that a chunk holds at most ``max_elements`` values of shape (T, C, N, Q): memory stays
bounded, and small chunks stay in the CPU cache (several times faster per value than large ones).

Every trial's draw depends only on ``(seed, level, trial index)``, never on which other trials
share its batch, so a protocol can be split, resumed or sharded and gives the same trials.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import torch

from msam_torch.config.schema import Config
from msam_torch.data.loading import load_datasets
from msam_torch.data.systems import perturb_parameters
from msam_torch.engine.candidates import EquationData, equation_choices
from msam_torch.engine.trainer import Fit, Trainer
from msam_torch.model.spec import Equation
from msam_torch.run.adapt import equation_result
from msam_torch.run.plan import Plan, make_trainer, prepare
from msam_torch.run.result import EquationResult

MAX_ELEMENTS = 2**18  # values of one (T, C, N, Q) tensor per chunk: 2 MiB in float64, cache-sized


@dataclass(frozen=True)
class Trial:
    """One draw: parametric error ``level`` (fraction, 0.5 = 50 %) and its index at that level."""

    level: float
    index: int


@dataclass(frozen=True)
class TrialResult:
    """The nominal parameters of a trial and the outcome of every state equation."""

    trial: Trial
    parameters: dict
    equations: list[EquationResult]


def trial_parameters(parameters: dict, trial: Trial, seed: int) -> dict:
    """The nominal parameters of ``trial``: ``perturb_parameters`` seeded by (seed, level, index)."""
    key = (int(seed) * 1_000_003 + round(trial.level * 1e6)) * 1_000_003 + trial.index
    generator = torch.Generator().manual_seed(key % (2**63))
    return perturb_parameters(parameters, trial.level, generator)


def chunk_size(trials: int, samples: int, adjustable: int, max_elements: int = MAX_ELEMENTS) -> int:
    """Candidates per chunk so that one (T, C, N, Q) tensor holds at most ``max_elements`` values."""
    return max(1, max_elements // max(1, trials * samples * max(1, adjustable)))


def concat_fits(fits: list[Fit]) -> Fit:
    """Fits of consecutive groups of trials as one Fit (the candidates are the same)."""
    if len(fits) == 1:
        return fits[0]
    join = lambda name: None if getattr(fits[0], name) is None else torch.cat([getattr(f, name) for f in fits])
    joined = {f.name: join(f.name) for f in dataclasses.fields(Fit) if f.name not in ("choices", "start", "adapted")}
    measures = lambda name: {k: torch.cat([getattr(f, name)[k] for f in fits]) for k in getattr(fits[0], name)}
    return Fit(choices=fits[0].choices, start=measures("start"), adapted=measures("adapted"), **joined)


def run_trials(config: Config, trials: Sequence[Trial], seed: int, base_dir: str | Path = ".",
               equation_options: dict | None = None, on_trainer: Callable[[Trainer, Equation], None] | None = None,
               max_elements: int = MAX_ELEMENTS) -> list[TrialResult]:
    """Algorithm 1 on every state equation of ``config`` for all ``trials`` at once.

    ``equation_options`` maps a target (``'x3_dot'``) to Trainer settings for that equation
    (``round_robin_steps``, ``refinement_steps``), as the paper uses per state (Table 3).
    """
    plan = prepare(config)
    spec = plan.spec
    train, _ = load_datasets(config.data, spec, base_dir, dtype=plan.dtype, estimator=plan.derivatives)
    signals = {k: v.to(plan.device) for k, v in train.signals.items()}
    parameters = [trial_parameters(spec.parameters, t, seed) for t in trials]
    per_equation = []
    for equation in spec.equations:
        fit, thetas, scale = fit_equation(plan, equation, signals, parameters, equation_options, on_trainer,
                                          max_elements)
        per_equation.append([equation_result(equation, fit, thetas[k], scale, k) for k in range(len(trials))])
    return [TrialResult(t, parameters[k], [results[k] for results in per_equation]) for k, t in enumerate(trials)]


def fit_equation(plan: Plan, equation: Equation, signals: dict, parameters: list[dict],
                 equation_options: dict | None = None, on_trainer: Callable[[Trainer, Equation], None] | None = None,
                 max_elements: int = MAX_ELEMENTS) -> tuple[Fit, torch.Tensor, torch.Tensor]:
    """One state equation for a batch of nominal parameter sets: the Fit, theta (T, Q + P), scale."""
    dtype, device = signals["t"].dtype, signals["t"].device
    data = EquationData.build(equation, signals, plan.config.adaptation.normalize)
    n, q = data.y.shape[-1], len(equation.adjustable)
    candidates = data.log_f.shape[-1] ** q
    thetas = torch.stack([plan.spec.theta(equation, p) for p in parameters]).to(device=device, dtype=dtype)
    group = max(1, max_elements // max(1, candidates * n * max(1, q)))  # trials per chunk
    start = torch.tensor([equation.components[i].start for i in equation.adjustable], dtype=dtype, device=device)
    fits = []
    for first in range(0, len(parameters), group):
        theta = thetas[first: first + group]
        trainer = make_trainer(plan)
        for key, value in (equation_options or {}).get(equation.target, {}).items():
            setattr(trainer, key, value)
        trainer.chunk_size = min(trainer.chunk_size, chunk_size(theta.shape[0], n, q, max_elements))
        if on_trainer is not None:
            on_trainer(trainer, equation)
        fits.append(trainer.fit(data.expand_trials(theta.shape[0]), theta[:, list(equation.adjustable)],
                                theta[:, list(equation.fixed)], start, choices=equation_choices(equation, theta.device)))
    return concat_fits(fits), thetas, data.scale[0]
