"""msam-torch: physics-first model repair with the Model Structure Adaptation Method.

The public names below are imported on first use (PEP 562), so ``import msam_torch`` and
``msam --help`` do not load torch, pandas or scipy; ``from msam_torch import adapt`` works as usual.
"""
from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_HOME = {  # public name -> the submodule that defines it
    "adapt": "run.adapt",
    "Candidate": "engine.candidates",
    "EquationData": "engine.candidates",
    "Config": "config.schema",
    "load_config": "config.schema",
    "ConfigError": "errors",
    "DataError": "errors",
    "MSAMError": "errors",
    "ModelSpec": "model.spec",
    "MSAM": "run.estimator",
    "StepOptions": "engine.step",
    "Trainer": "engine.trainer",
}

__all__ = [*_HOME, "__version__"]

if TYPE_CHECKING:  # the same names for type checkers and the API docs
    from msam_torch.run.adapt import adapt
    from msam_torch.engine.candidates import Candidate, EquationData
    from msam_torch.config.schema import Config, load_config
    from msam_torch.errors import ConfigError, DataError, MSAMError
    from msam_torch.run.estimator import MSAM
    from msam_torch.model.spec import ModelSpec
    from msam_torch.engine.step import StepOptions
    from msam_torch.engine.trainer import Trainer


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
