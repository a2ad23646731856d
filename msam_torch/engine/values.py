"""The values one MSAM step works on: its options (:class:`StepOptions`), the state of a batch of
candidates (:class:`State`), their evaluation (:class:`Evaluation`, fitness Eq. 19), the step's
outcome (:class:`StepResult`, Eq. 15-18), and the :class:`Evaluator` protocol that evaluates and
steps them (algebraically, :class:`~msam_torch.engine.trainer.Algebraic`, or by simulation,
:class:`~msam_torch.simulation.evaluator.SimulationEvaluator`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch

from msam_torch.config.schema import ThetaRule
from msam_torch.engine.step_rules import STEP_SIZES, StepSizeRule


@dataclass(frozen=True)
class StepOptions:
    """How a step is taken. Defaults follow the paper (section 4). ``step_size`` is a rule or the
    name of one in :data:`~msam_torch.engine.step_rules.STEP_SIZES`, ``theta`` a
    :class:`~msam_torch.config.schema.ThetaRule` or its name; names become the objects here."""

    dgamma: float = 1e-2  # exponent perturbation of Eq. 15-16
    scaling: str = "dm"  # 'dm': solve and step in dM-scaled units (Eq. 16-18); 'gauss_newton'
    step_size: StepSizeRule | str = "eq20"  # Eq. 20 (mu = corr(eps, Phi dGamma)), 'one', 'line_search'
    theta: ThetaRule | str = ThetaRule.FIXED  # nominal theta, or 'varpro' (theta re-solved every step)
    damping: float = 0.0  # Levenberg-Marquardt damping on the column-equilibrated normal equations
    gamma_limit: float = 20.0  # |gamma| beyond which a candidate is marked diverged
    rcond: float = 1e-12  # relative eigenvalue cut-off of the least-squares solves

    def __post_init__(self):
        object.__setattr__(self, "step_size", STEP_SIZES.resolve(self.step_size))
        object.__setattr__(self, "theta", ThetaRule(self.theta))


@dataclass(frozen=True)
class State:
    """Exponents and theta of a batch of candidates: (T, C, Q), (T, C, Q), (T, C, P), (T, C).

    ``initial`` (T, C, S): estimated initial states, used by simulation-based evaluation only.
    ``settled`` (T, C): the last line search found no step size that raises the fitness, so the
    exponents did not move; the step being a function of the state alone, the next search would
    find none again, and it is skipped.
    """

    gamma: torch.Tensor
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    diverged: torch.Tensor
    initial: torch.Tensor | None = None
    settled: torch.Tensor | None = None


@dataclass(frozen=True)
class Evaluation:
    """A state evaluated on the data: columns, output, error and fitness (Eq. 19)."""

    cols: torch.Tensor  # (T, C, N, Q)
    yhat: torch.Tensor  # (T, C, N)
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    fitness: torch.Tensor  # (T, C)
    sum_abs_error: torch.Tensor
    rho: torch.Tensor
    initial: torch.Tensor | None = None  # (T, C, S) initial states simulated from (simulation mode)
    design_gram: torch.Tensor | None = None  # D^T D of [cols, fixed components] (theta re-solved)


@dataclass(frozen=True)
class StepResult:
    """The new state and what the step saw: mu, the solution, dM and condition numbers."""

    state: State
    mu: torch.Tensor  # (T, C)
    delta: torch.Tensor  # (T, C, Q) the least-squares solution of Eq. 17
    dm: torch.Tensor  # (T, C, Q) Eq. 15
    cond_scaled: torch.Tensor | None  # (T, C) cond(Phi^T Phi) with dM scaling (None unless asked for)
    cond_unscaled: torch.Tensor | None  # (T, C) without



@runtime_checkable
class Evaluator(Protocol):
    """Evaluates and steps a batch of candidates; ``selection`` is ``data.select(choices)`` of the
    data the trainer was given (:class:`~msam_torch.engine.candidates.EquationData` for ``algebraic``).
    ``simulates`` (optional, default False) says which data it reads: the estimated states and
    derivatives of a record (Eq. 6), or the record as simulation sees it (free runs under the
    measured inputs); :func:`~msam_torch.run.adapt.adapt` and the diagnosis prepare that data."""

    def evaluate(self, selection, state: State, options: StepOptions) -> Evaluation:
        """Output, error and fitness (Eq. 19) of every candidate at ``state``."""
        ...

    def step(self, selection, state: State, current: Evaluation, options: StepOptions,
             conditions: bool = True) -> StepResult:
        """One iteration of Eq. 15-18; ``conditions``: also the condition numbers of Figure 5."""
        ...

    def starting_measures(self, data, theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
        """Measures (fitness, sum_abs_error, rho; each (T,)) of the unadjusted starting model."""
        ...


def simulates(evaluator) -> bool:
    """Whether ``evaluator`` judges candidates by simulation (its ``simulates``; absent: algebraically)."""
    return bool(getattr(evaluator, "simulates", False))
