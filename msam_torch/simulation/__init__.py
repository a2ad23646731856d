"""Simulation: the one ODE model of Eq. 9 (:mod:`.model`), the one :func:`simulate` (:mod:`.solver`),
records from the project's loader (:mod:`.record`), exact forward-mode sensitivities
(:mod:`.sensitivities`), the simulation evaluator of Algorithm 1 (:mod:`.evaluator`), adaptation
from a config (:mod:`.adapt`, imported on its own: it builds results), free runs (:mod:`.free_run`) and per-equation models for the
diagnosis (:mod:`.equations`)."""
from msam_torch.simulation.equations import EquationModel, simulate_equations
from msam_torch.simulation.evaluator import SimulationEvaluator
from msam_torch.simulation.free_run import FreeRun, free_run_models, free_runs
from msam_torch.simulation.ode import Parameters, SystemModel, build_model, groups, output_states, state_limits
from msam_torch.simulation.problem import SimulationData
from msam_torch.simulation.record import Record, load_records
from msam_torch.simulation.sensitivities import jacobians
from msam_torch.simulation.solver import simulate

__all__ = ["EquationModel", "FreeRun", "Parameters", "Record", "SimulationData", "SimulationEvaluator",
           "SystemModel", "build_model", "free_run_models", "free_runs", "groups", "jacobians",
           "load_records", "output_states", "simulate", "simulate_equations", "state_limits"]
