"""msam-torch: physics-first model repair with the Model Structure Adaptation Method.

The public face: :func:`adapt` and :class:`MSAM` (MSAM on every state equation of a config),
:func:`diagnose` (where the sim-to-real gap lies, which effect causes it, how far it shrinks),
:func:`load_config`, the options, results and errors. Everything else lives in the subpackages
(config, model, data, engine, simulation, run, diagnosis, cli, zoo) and may change.
The names are imported on first use (PEP 562), so ``import msam_torch`` and ``msam --help`` do
not load torch, pandas or scipy; ``from msam_torch import adapt`` works as usual.
"""
from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_HOME = {  # public name -> the module that defines it
    "adapt": "run.adapt",
    "MSAM": "estimator",
    "diagnose": "diagnosis.stages.pipeline",
    "load_config": "config.schema",
    "Config": "config.schema",
    "DiagnoseOptions": "diagnosis.options",
    "StepOptions": "engine.values",
    "Trainer": "engine.trainer",
    "RunResult": "run.result",
    "GapReport": "diagnosis.report.gap_report",
    "StateModel": "run.state_model",
    "MSAMError": "errors",
    "ConfigError": "errors",
    "DataError": "errors",
    "NoInformation": "errors",
}

__all__ = [*_HOME, "__version__"]

if TYPE_CHECKING:  # the same names for type checkers and the API docs
    from msam_torch.config.schema import Config, load_config
    from msam_torch.diagnosis.options import DiagnoseOptions
    from msam_torch.diagnosis.report.gap_report import GapReport
    from msam_torch.diagnosis.stages.pipeline import diagnose
    from msam_torch.engine.trainer import Trainer
    from msam_torch.engine.values import StepOptions
    from msam_torch.errors import ConfigError, DataError, MSAMError, NoInformation
    from msam_torch.estimator import MSAM
    from msam_torch.run.adapt import adapt
    from msam_torch.run.result import RunResult
    from msam_torch.run.state_model import StateModel


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
