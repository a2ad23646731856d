"""msam-torch: physics-first model repair with the Model Structure Adaptation Method."""
__version__ = "0.1.0"

from .api import adapt
from .candidates import Candidate, EquationData
from .config import Config, load_config
from .errors import ConfigError, DataError, MSAMError
from .spec import ModelSpec
from .step import StepOptions
from .trainer import Trainer

__all__ = ["adapt", "Candidate", "EquationData", "Config", "load_config", "ConfigError", "DataError",
           "MSAMError", "ModelSpec", "StepOptions", "Trainer", "__version__"]
