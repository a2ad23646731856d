"""How candidates are judged: the :class:`Evaluator` protocol the :class:`~msam_torch.engine.trainer.Trainer`
calls, and :data:`EVALUATORS`, the registry ``adaptation.evaluation`` names one from.

- ``algebraic`` (:class:`msam_torch.engine.trainer.Algebraic`, the default): candidate outputs from the
  estimated states, one step ahead (paper section 2, Eq. 6-7);
- ``simulation`` (:class:`msam_torch.simulation.evaluator.SimulationEvaluator`): candidates simulated
  under the measured inputs and compared on the measured outputs (the paper's section 2 alternative).

Both are defined in modules that depend on the config schema, which imports this registry; they are
registered by their module paths and imported when first chosen (:class:`~msam_torch.config.registry.Registry`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

from msam_torch.config.registry import Registry

if TYPE_CHECKING:
    import torch

    from msam_torch.engine.step import Evaluation, State, StepOptions, StepResult


@runtime_checkable
class Evaluator(Protocol):
    """Evaluates and steps a batch of candidates; ``selection`` is ``data.select(choices)`` of the
    data the trainer was given (:class:`~msam_torch.engine.candidates.EquationData` for ``algebraic``)."""

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


EVALUATORS: Registry[Evaluator] = Registry("adaptation.evaluation", Evaluator, "evaluator")
EVALUATORS.register("algebraic", "msam_torch.engine.trainer:Algebraic")
EVALUATORS.register("simulation", "msam_torch.simulation.evaluator:SimulationEvaluator")
