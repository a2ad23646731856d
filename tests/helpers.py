"""Small shared builders for the tests."""
from pathlib import Path

import torch

from msam_torch.candidates import EquationData
from msam_torch.config import load_config
from msam_torch.spec import ModelSpec
from msam_torch.systems import SYSTEMS, simulate

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def equation_data(name: str = "harmonic", equation: int = 0, normalize: str = "none"):
    """EquationData, nominal theta (adjustable, fixed) and the spec of a bundled config."""
    config = load_config(CONFIGS / f"{name}.yaml")
    spec = ModelSpec.from_config(config.model)
    eq = spec.equations[equation]
    data = EquationData.build(eq, simulate(SYSTEMS[config.data.system]), normalize)
    theta = spec.theta(eq)
    return data, theta[list(eq.adjustable)], theta[list(eq.fixed)], eq
