"""How candidates are judged: :data:`EVALUATORS`, the registry ``adaptation.evaluation`` names an
:class:`~msam_torch.engine.values.Evaluator` from.

- ``algebraic`` (:class:`msam_torch.engine.trainer.Algebraic`, the default): candidate outputs from the
  estimated states, one step ahead (paper section 2, Eq. 6-7);
- ``simulation`` (:class:`msam_torch.simulation.evaluator.SimulationEvaluator`): candidates simulated
  under the measured inputs and compared on the measured outputs (the paper's section 2 alternative).
"""
from __future__ import annotations

from msam_torch.config.registry import Registry
from msam_torch.engine.trainer import Algebraic
from msam_torch.engine.values import Evaluator
from msam_torch.simulation.evaluator import SimulationEvaluator

EVALUATORS: Registry[Evaluator] = Registry("adaptation.evaluation", Evaluator, "evaluator")
EVALUATORS.register("algebraic", Algebraic)
EVALUATORS.register("simulation", SimulationEvaluator)
