"""A verdict does not depend on the unit of the time column: the same record with time in
seconds, milliseconds or hours (and the starting model's coefficients converted) gives the same
verdict, the same exponent and the same dimensionless measures (the held-out improvement, the
free runs' NRMSE)."""
import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp

from msam_torch.data.systems import get_system, measure
from msam_torch.diagnosis import Verdict, diagnose

SCALES = {"s": 1.0, "ms": 1000.0, "h": 1 / 3600}  # time units per second


def tank(scale: float):
    """A pumped tank with Torricelli outflow; the starting model's outflow is linear (3001 samples:
    with 3000, the test functions' half-width falls within 1e-4 of a half sample, where rounding
    it to whole samples goes either way with the last bit of the time column)."""
    t = np.linspace(0.0, 600.0, 3001)
    pump = 0.035 + 0.015 * np.sin(2 * np.pi * t / 150) + 0.01 * np.sin(2 * np.pi * t / 47 + 1)
    rhs = lambda s, h: [(np.interp(s, t, pump) - 0.01 * np.sqrt(2 * 9.81 * max(h[0], 0.0))) / 0.5]
    level = solve_ivp(rhs, (0, 600), [0.5], t_eval=t, rtol=1e-9, atol=1e-12, max_step=0.5).y[0]
    level = level + 0.01 * level.std() * np.random.default_rng(0).standard_normal(t.size)
    frame = pd.DataFrame({"time": t * scale, "level": level, "pump": pump / scale})
    model = {"states": ["h"], "inputs": ["q"], "quantities": {"h": "level", "q": "flow"},
             "parameters": {"A": 0.5, "k": 0.04 / scale},
             "equations": [{"target": "h_dot", "components": [
                 {"term": "h", "theta": "-k/A"}, {"term": "q", "theta": "1/A", "adjustable": False}],
                 "adjustments": ["abs(h)"]}]}
    return {"model": model, "data": {"time": "time", "columns": {"h": "level", "q": "pump"}}}, frame


def coulomb(scale: float):
    """The bundled mass-spring-damper with Coulomb friction, the displacement measured."""
    signals = measure(get_system("msd_coulomb"))
    x = signals["x"].numpy()
    frame = pd.DataFrame({"time": signals["t"].numpy() * scale, "x": x + 0.01 * x.std() * np.random.default_rng(1)
                          .standard_normal(x.size), "u": signals["u"].numpy()})
    model = {"states": ["x", "x_dot"], "inputs": ["u"],
             "parameters": {"c": 0.5 / scale, "k": 4.0 / scale ** 2, "b": 1 / scale ** 2},
             "equations": [{"target": "x_ddot", "components": [
                 {"term": "x_dot", "theta": "-c"}, {"term": "x", "theta": "-k"},
                 {"term": "u", "theta": "b", "adjustable": False}], "adjustments": ["abs(x_dot)", "abs(x)"]}]}
    return {"model": model, "data": {"time": "time", "columns": {"x": "x", "u": "u"}}}, frame


@pytest.mark.slow
@pytest.mark.parametrize("case, effect", [(tank, "Torricelli outflow"), (coulomb, "Coulomb friction")])
def test_the_verdict_is_the_same_in_seconds_milliseconds_and_hours(case, effect):
    found = {}
    for unit, scale in SCALES.items():
        config, frame = case(scale)
        report = diagnose(config, data=frame)
        gap = report.equations[0]
        assert gap.verdict_kind is Verdict.EXPLAINED and gap.effect == effect, unit
        nrmse = report.measures["free_run"]["train"]["nrmse"]
        found[unit] = (gap.exponent, gap.improvement["relative"], [nrmse[m] for m in ("start", "retuned", "adapted")])
    assert found["s"][1] > 0.5 and found["s"][2][2] < 0.5 * found["s"][2][1]  # a real gain to compare
    for unit in ("ms", "h"):
        assert found[unit][0] == pytest.approx(found["s"][0], abs=1e-4), unit
        assert found[unit][1] == pytest.approx(found["s"][1], abs=1e-4), unit
        assert found[unit][2] == pytest.approx(found["s"][2], rel=1e-3), unit
