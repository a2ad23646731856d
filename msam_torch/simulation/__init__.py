"""Simulation: the one ODE model of Eq. 9 (:mod:`.model`), the one :func:`simulate` (:mod:`.solver`),
records from the project's loader (:mod:`.record`), exact forward-mode sensitivities
(:mod:`.sensitivities`), the simulation evaluator of Algorithm 1 (:mod:`.evaluator`), adaptation
from a config (:mod:`.adapt`), free runs (:mod:`.free_run`) and per-equation models for the
diagnosis (:mod:`.equations`)."""
from .adapt import Prepared, adapt_simulation, prepare_group
from .equations import EquationModel, simulate_equations
from .evaluator import SimulationEvaluator
from .free_run import FreeRun, free_run_models, free_runs
from .model import Parameters, SystemModel, build_model, groups, output_states, state_limits
from .problem import SimulationData
from .record import Record, load_records
from .sensitivities import jacobians
from .solver import simulate

__all__ = ["EquationModel", "FreeRun", "Parameters", "Prepared", "Record", "SimulationData", "SimulationEvaluator",
           "SystemModel", "adapt_simulation", "build_model", "free_run_models", "free_runs", "groups", "jacobians",
           "load_records", "output_states", "prepare_group", "simulate", "simulate_equations", "state_limits"]
