"""Small shared builders for the tests, and the quick options most of them run with."""
from functools import lru_cache
from pathlib import Path

import pytest

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.systems import SYSTEMS, measure
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.engine.candidates import EquationData

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

QUICK = ["adaptation.round_robin_steps=3", "adaptation.refinement_steps=2"]  # a run: few steps of Algorithm 1
ONE_STEP = DiagnoseOptions(bootstrap=0, steps=20, free_run=False)  # a diagnosis: no bootstrap, no free runs


def equation_data(name: str = "harmonic", equation: int = 0, normalize: str = "none"):
    """EquationData, nominal theta (adjustable, fixed) and the spec of a bundled config."""
    config = load_config(CONFIGS / f"{name}.yaml")
    spec = to_spec(config.model)
    eq = spec.equations[equation]
    data = EquationData.build(eq, measure(SYSTEMS[config.data.system]), normalize)
    theta = spec.theta(eq)
    return data, theta[list(eq.adjustable)], theta[list(eq.fixed)], eq


@lru_cache(maxsize=None)
def simulated(system: str) -> dict:
    """The signals of a bundled system as numpy arrays, simulated once per test session."""
    return {k: v.numpy() for k, v in measure(SYSTEMS[system]).items()}


def measured_case(name: str = "harmonic", length: float = 1.0, time: float = 1.0, every: int = 1):
    """A bundled config turned into a measured-data config (dict) and the simulated signals as a
    DataFrame in other units: lengths times ``length``, times times ``time``, nominal parameters
    converted alike, so the model and data describe the same system. ``every`` thins the samples."""
    import pandas as pd
    import yaml

    config = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    signals = {k: v[::every] for k, v in simulated(config["data"]["system"]).items()}
    frame = pd.DataFrame({"t": signals["t"] * time, "x": signals["x"] * length,
                          "x_dot": signals["x_dot"] * length / time, "x_ddot": signals["x_ddot"] * length / time**2})
    p = config["model"]["parameters"]
    if name == "harmonic":  # u stays in N; the starting model's c/m [1/s], k/m [1/s^2], 1/m [L/(N s^2)] convert
        frame["u"] = signals["u"]
        p = {"m": p["m"] * time**2 / length, "c": p["c"] * time / length, "k": p["k"] / length}
    elif name == "vanderpol":  # eta1, eta2 [1/s], eta3 [1/s^2] in the starting model
        p = {"eta1": p["eta1"] / time, "eta2": p["eta2"] / time, "eta3": p["eta3"] / time**2}
    else:
        raise ValueError(name)
    config["model"]["parameters"] = p
    config["data"] = {"time": "t", "columns": {c: c for c in frame.columns if c != "t"}, "derivatives": "exact"}
    return config, frame


def slow_folder(conftest: str):
    """The collection hook of a folder whose tests all belong to the slow tier (``pytest -m slow``):
    its ``conftest.py`` sets ``pytest_collection_modifyitems = slow_folder(__file__)``."""
    here = Path(conftest).resolve().parent

    @pytest.hookimpl(tryfirst=True)
    def pytest_collection_modifyitems(items):
        for item in items:
            if here in item.path.parents:
                item.add_marker(pytest.mark.slow)

    return pytest_collection_modifyitems
