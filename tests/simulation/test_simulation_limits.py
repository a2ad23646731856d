"""Saturated states (``simulation.saturation``) and per-component adjustment sets."""
import copy

import numpy as np
import pandas as pd
import pytest
import torch
from torchdiffeq import odeint

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.engine.candidates import equation_choices
from msam_torch.errors import ConfigError
from msam_torch.run.adapt_simulated import prepare_group
from msam_torch.run.plan import prepare
from msam_torch.simulation.ode import build_model
from tests.simulation.test_simulation_mode import TANKS

LINEAR = {"k1": 0.05, "k2": 0.05, "k3": 0.04, "k4": 0.05}


def saturated_record(path, limit: float, n: int = 60, dt: float = 4.0) -> int:
    """Linear two tanks (the parameters of LINEAR) whose lower level stops at ``limit``; writes
    u and y = x2 and returns how many readings sit at the limit."""
    rng = np.random.default_rng(1)
    u = np.repeat(rng.uniform(1.0, 9.0, n // 10 + 1), 10)[:n]
    t = torch.arange(n, dtype=torch.float64) * dt
    u_t = torch.as_tensor(u)

    def rhs(time, x):
        k = torch.clamp((time / dt + 1e-9).long(), max=n - 1)
        rate = torch.stack([-LINEAR["k1"] * x[0] + LINEAR["k4"] * u_t[k], LINEAR["k2"] * x[0] - LINEAR["k3"] * x[1]])
        return torch.where((x >= torch.tensor([torch.inf, limit])) & (rate > 0), 0.0, rate)

    x = odeint(rhs, torch.tensor([2.0, 3.0], dtype=torch.float64), t, method="midpoint", options={"step_size": dt})
    y = x[:, 1].clamp(max=limit).numpy()
    pd.DataFrame({"t": t.numpy(), "u": u, "y": y}).to_csv(path, index=False)
    return int((y >= limit).sum())


def linear_tanks(saturation: dict | None) -> dict:
    raw = copy.deepcopy(TANKS)
    raw["model"]["parameters"] = {k: 0.95 * v for k, v in LINEAR.items()}  # a 5 % parametric error to fit away (20 %: a local minimum at the saturation)
    sim = raw["adaptation"]["simulation"]
    sim.update({"method": "midpoint", "prefit_steps": 12, "initial_guess": {"x1": 2.0}})
    if saturation is not None:
        sim["saturation"] = saturation
    return raw


def test_saturation_lets_the_starting_fit_match_a_record_with_a_saturated_level(tmp_path):
    limit = 6.0
    at_limit = saturated_record(tmp_path / "tanks.csv", limit)
    assert 5 <= at_limit <= 40  # the record saturates, but not throughout

    def fitted(saturation):
        config = load_config(linear_tanks(saturation))
        spec = to_spec(config.model)
        prepared = prepare_group(prepare(config), spec.equations, config.model.parameters, tmp_path)
        data = prepared.data
        unadjusted = torch.full_like(prepared.theta, data.model.unadjusted, dtype=torch.long)
        yhat = data.output(torch.zeros_like(prepared.theta), unadjusted, prepared.theta, prepared.theta_fixed, data.initial)
        return float(torch.sqrt(((data.y - yhat) ** 2).mean())), prepared, yhat

    rmse_limited, prepared, yhat = fitted({"x2": [None, limit]})
    rmse_free, _, _ = fitted(None)
    assert float(yhat.max()) <= limit  # the compared output never leaves the range
    assert rmse_limited < 1e-3 < 0.05 < rmse_free  # only the saturated simulation matches the record
    theta = torch.cat([prepared.theta[0], prepared.theta_fixed[0]])  # k1, k2, k3 (adjustable), k4 (fixed)
    expected = torch.tensor([-LINEAR["k1"], LINEAR["k2"], -LINEAR["k3"], LINEAR["k4"]], dtype=theta.dtype)
    # x1 is not measured: its scale is free, so compare the scale-free combinations k3 and k1, k2 k4
    torch.testing.assert_close(theta[[0, 2]], expected[[0, 2]], rtol=1e-2, atol=0)
    torch.testing.assert_close(theta[1] * theta[3], expected[1] * expected[3], rtol=1e-2, atol=0)


def test_saturation_errors_name_the_key(tmp_path):
    saturated_record(tmp_path / "tanks.csv", 6.0, n=20)
    for saturation, message in (({"x3": [None, 1.0]}, "not a state"), ({"x2": [5.0, 1.0]}, "empty")):
        config = load_config(linear_tanks(saturation))
        spec = to_spec(config.model)
        with pytest.raises(ConfigError, match=message) as info:
            prepare_group(prepare(config), spec.equations, LINEAR, tmp_path)
        assert "adaptation.simulation.saturation" in str(info.value)


def component_sets(first: list[str], second: list[str] | None = None) -> dict:
    raw = copy.deepcopy(TANKS)
    components = raw["model"]["equations"][1]["components"]
    components[0]["adjustments"] = first
    if second is not None:
        components[1]["adjustments"] = second
    return raw


def test_component_adjustment_sets_restrict_the_candidates():
    spec = to_spec(load_config(component_sets(["abs(x1)"], ["abs(x2)"])).model)
    x2_dot = spec.equations[1]
    assert equation_choices(x2_dot).tolist() == [[0, 1]]
    assert build_model(spec, spec.equations).choices().tolist() == [[0, 0, 1]]  # joint: functions (abs(x1), abs(x2))
    partial = to_spec(load_config(component_sets(["abs(x2)"])).model).equations[1]
    assert equation_choices(partial).tolist() == [[1, 0], [1, 1]]  # the unrestricted component keeps both
    unrestricted = to_spec(load_config(TANKS).model).equations[1]
    assert equation_choices(unrestricted).tolist() == [[0, 0], [0, 1], [1, 0], [1, 1]]


@pytest.mark.parametrize("functions, message", [(["x2"], "not one of the equation's adjustments"),
                                                (["abs(x1)", "abs(x1)"], "listed twice")])
def test_component_adjustment_errors_name_the_key(functions, message):
    with pytest.raises(ConfigError, match=message) as info:
        to_spec(load_config(component_sets(functions)).model)
    assert "model.equations[1].components[0].adjustments" in str(info.value)
