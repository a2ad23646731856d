"""Free runs of stiff models: the fixed step starts within the stability interval of the fastest
decaying mode (:func:`msam_torch.simulation.equations.fastest_decay`), not only at a share of the
band's period."""
import numpy as np
import pandas as pd
import pytest
import torch
from scipy.integrate import solve_ivp

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.diagnosis import DiagnoseOptions, Verdict, diagnose
from msam_torch.diagnosis.compare.comparison import STABLE_SHARE
from msam_torch.model.spec import ModelSpec
from msam_torch.simulation.equations import EquationModel, fastest_decay
from msam_torch.simulation.solver import STABILITY

# a DC motor: current with an electrical pole at R/L = 600 per second, speed with a mechanical one
A = np.array([[-600.0, -2.6], [2400.0, -0.5]])
B = np.array([500.0, 0.0])
MODEL = {"states": ["i", "w"], "inputs": ["V"],
         "parameters": {"a": 600.0, "k": 2.6, "b": 500.0, "c": 2400.0, "d": 0.5},
         "quantities": {"i": "current", "w": "angular_velocity", "V": "voltage"},
         "equations": [{"target": "i_dot", "components": [{"term": "i", "theta": "-a"}, {"term": "w", "theta": "-k"},
                                                         {"term": "V", "theta": "b", "adjustable": False}],
                        "adjustments": ["abs(i)", "abs(w)"]},
                       {"target": "w_dot", "components": [{"term": "i", "theta": "c"}, {"term": "w", "theta": "-d"}],
                        "adjustments": ["abs(w)", "abs(i)"]}]}


def _record(seed: int) -> pd.DataFrame:
    t = np.arange(2500) * 0.002
    phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, 6)
    wave = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(np.linspace(0.1, 2.0, 6), phases))
    voltage = lambda s: np.interp(s, t, 6 * wave / np.abs(wave).max())
    x = solve_ivp(lambda s, x: A @ x + B * voltage(s), (t[0], t[-1]), [0.0, 0.0], t_eval=t, method="LSODA",
                  rtol=1e-10, atol=1e-12).y
    return pd.DataFrame({"t": t, "i": x[0], "w": x[1], "V": voltage(t)})


def _models(spec: ModelSpec, current: list[float], speed: list[float]) -> list[EquationModel]:
    """The starting model with these theta per equation, two identical rows."""
    rows = lambda values: torch.tensor([values, values], dtype=torch.float64)
    return [EquationModel.starting(eq, rows(values)) for eq, values in zip(spec.equations, (current, speed))]


def test_the_fastest_decaying_mode_of_a_linear_model_is_its_largest_stable_eigenvalue():
    spec = to_spec(load_config({"model": MODEL}).model)
    points = {"t": torch.zeros(3, dtype=torch.float64), "i": torch.tensor([0.0, 1.0, -2.0], dtype=torch.float64),
              "w": torch.tensor([0.0, 10.0, 3.0], dtype=torch.float64), "V": torch.ones(3, dtype=torch.float64)}
    decaying = lambda a: max((abs(v) for v in np.linalg.eigvals(a) if v.real < 0), default=0.0)
    found = fastest_decay(spec, _models(spec, [-600.0, -2.6, 500.0], [2400.0, -0.5]), points)
    np.testing.assert_allclose(found.numpy(), [decaying(A)] * 2, rtol=1e-12)
    # a growing mode bounds no step: only the decaying one counts
    growing = np.array([[-600.0, -2.6], [-2400.0, 40.0]])
    assert max(v.real for v in np.linalg.eigvals(growing)) > 0 and decaying(growing) > 0
    found = fastest_decay(spec, _models(spec, [-600.0, -2.6, 500.0], [-2400.0, 40.0]), points)
    np.testing.assert_allclose(found.numpy(), [decaying(growing)] * 2, rtol=1e-12)


@pytest.mark.slow
def test_the_exact_model_of_a_stiff_motor_simulates_within_its_stability_interval():
    """The band and the 5 s record ask for a 10 ms step, at which rk4 diverges on the 600 per second pole
    (every free run diverged, and the exact model read "inconclusive"): the step now starts at
    most at 0.9 x 2.785 / 600 / 2 = 2.1 ms (the check's run at twice it is stable too), and the
    exact model reads "no significant gap"."""
    config = {"model": MODEL, "data": {"time": "t", "columns": {k: k for k in ("i", "w", "V")}}}
    report = diagnose(config, data=_record(1), validation=_record(2), options=DiagnoseOptions(bootstrap=0))
    assert report.verdict_kind is Verdict.NO_GAP, report.reasons
    decay = max(abs(v) for v in np.linalg.eigvals(A) if v.real < 0)
    for label, run in report.measures["free_run"].items():
        assert run["diverged"] == [] and run["solver"]["converged"], (label, run)
        assert run["solver"]["step"] <= STABLE_SHARE * STABILITY["rk4"] / (2 * decay) * (1 + 1e-9), run["solver"]
        assert run["nrmse"]["start"] < 0.01, run["nrmse"]


@pytest.mark.slow
def test_a_step_the_check_accepts_at_once_is_doubled_while_it_agrees(monkeypatch):
    """The band's rule only sets where the step search starts: started at an eighth of the sample
    period on a slow oscillator (2 Hz resonance sampled at 100 Hz), the step is doubled while the
    runs at it and at twice it agree, up to half the sample period (twice that is the longest
    check run that meets every sample), and the exact model's free runs stay on the record."""
    import msam_torch.diagnosis.compare.comparison as compare

    dt = 0.01
    t = np.arange(4000) * dt
    rng = np.random.default_rng(3)
    wave = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(np.linspace(0.2, 6.0, 8), rng.uniform(0, 2 * np.pi, 8)))
    force = lambda s: np.interp(s, t, wave / np.abs(wave).max())
    a = np.array([[0.0, 1.0], [-(2 * np.pi * 2.0) ** 2, -1.0]])
    x = solve_ivp(lambda s, x: a @ x + np.array([0.0, 50.0]) * force(s), (t[0], t[-1]), [0.0, 0.0], t_eval=t,
                  method="LSODA", rtol=1e-10, atol=1e-12).y
    record = lambda part: pd.DataFrame({"t": t[part], "x": x[0][part], "x_dot": x[1][part], "F": force(t[part])})
    model = {"states": ["x", "x_dot"], "inputs": ["F"], "parameters": {"k": float(-a[1, 0]), "d": 1.0, "b": 50.0},
             "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-d"}, {"term": "x", "theta": "-k"},
                                                              {"term": "F", "theta": "b"}],
                            "adjustments": ["abs(x)", "abs(x_dot)"]}]}
    started = []
    first_step = compare._first_step

    def at_an_eighth(*args, **kwargs):
        step, stiff, widest = first_step(*args, **kwargs)
        started.append(step)
        return dt / 8, stiff, widest

    monkeypatch.setattr(compare, "_first_step", at_an_eighth)
    config = {"model": model, "data": {"time": "t", "columns": {k: k for k in ("x", "x_dot", "F")}}}
    report = diagnose(config, data=record(slice(0, 2000)), validation=record(slice(2000, 4000)),
                      options=DiagnoseOptions(bootstrap=0))
    assert started, "the free runs' step search did not run"
    for label, run in report.measures["free_run"].items():
        assert run["solver"]["converged"] and run["diverged"] == [], (label, run["solver"])
        assert abs(run["solver"]["step"] - dt / 2) < 1e-12, (label, run["solver"])
        assert run["nrmse"]["start"] < 0.01, (label, run["nrmse"])
