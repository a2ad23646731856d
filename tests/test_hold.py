"""Inputs held between samples (zero-order hold) in the weak form (msam_torch.hold)."""
import numpy as np
import pytest
from numpy.polynomial import polynomial as P

from msam_torch.diagnose import DiagnoseOptions, diagnose
from msam_torch.hold import is_held, kink_corrected, quadrature_values, represent
from msam_torch.zoo import excitation

QUICK = DiagnoseOptions(bootstrap=0, steps=20, free_run=False, max_effects=1)


def test_a_held_input_is_told_from_a_sampled_continuous_one():
    rng = np.random.default_rng(0)
    prbs = np.repeat(rng.choice([-1.0, 1.0], 400), 3)  # bits of 3 samples
    assert is_held(prbs)
    assert not is_held(np.sin(0.05 * np.arange(1200)))
    assert not is_held(np.ones(100))  # a constant has no intersample behaviour to tell
    assert quadrature_values(np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])).tolist() == pytest.approx(
        [0.0, 0.0, -1 / 24, 0.5, 25 / 24, 1.0])
    signals, behaviour, _ = represent({"t": np.arange(1200.0), "u": prbs, "x": prbs}, ["u"], "auto")
    assert behaviour == {"u": "zoh"} and signals["x"] is prbs
    assert signals["u"][5] == pytest.approx((-prbs[3] + 13 * prbs[4] + 13 * prbs[5] - prbs[6]) / 24)
    assert represent({"u": prbs}, ["u"], "linear")[1] == {"u": "linear"}


@pytest.mark.parametrize("half_width, most", [(5, 0.006), (8, 0.001)])
def test_quadrature_values_integrate_a_held_input_to_fourth_order(half_width, most):
    """Against bump test functions, the trapezoid rule on the quadrature values matches the exact
    integral of the held input (cell by cell, the bump's antiderivative) within ``most`` (relative
    RMS), several times closer than the cell averages ``(u[k-1] + u[k]) / 2``."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1.0, 1.0, 200), 3)
    bump = P.polypow([1.0, 0.0, -1.0], 4)  # (1 - s^2)^4
    s = np.linspace(-1.0, 1.0, 2 * half_width + 1)
    cells = (P.polyval(s[1:], P.polyint(bump)) - P.polyval(s[:-1], P.polyint(bump))) * half_width
    phi = P.polyval(s, bump)
    starts = range(2, u.size - 2 * half_width - 2, 3)
    exact = np.array([u[k:k + 2 * half_width] @ cells for k in starts])
    error = lambda v: np.sqrt(np.mean([(v[k:k + 2 * half_width + 1] @ phi - e) ** 2 for k, e in zip(starts, exact)]))
    averages = np.concatenate([u[:1], 0.5 * (u[:-1] + u[1:])])
    scale = np.sqrt(np.mean(exact**2))
    assert error(quadrature_values(u)) / scale < most < error(averages) / scale / 4


def test_zoo_steps_and_prbs_switch_only_at_sampling_instants():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 100.0, 8 * 1000 + 1)  # the zoo's dense grid: 8 points per sample of 0.1
    for kind in ("steps", "prbs"):
        e, _ = excitation.draw(rng, t, 10.0, kind, fraction=0.2)
        switches = np.flatnonzero(np.diff(e)) + 1
        assert switches.size > 10 and np.all(switches % 8 == 0)


@pytest.mark.parametrize("rate, noise, corrected", [(2.0, 0.0, True), (60.0, 0.0, False), (2.0, 0.1, False)])
def test_kinks_are_corrected_only_where_the_data_resolve_them(rate, noise, corrected):
    """A first-order state under a held input kinks at each switch; resolved (time constant 25
    samples), its switch samples move by a twelfth of their second difference; one that settles
    within a sample (time constant 0.8 samples) or buried in noise (10 % of its range) is left as it is."""
    record = _first_order_record("zoh", 0, rate)
    x = record["x"] + noise * np.random.default_rng(1).standard_normal(record["x"].size)
    switches = np.diff(record["u"], prepend=record["u"][:1]) != 0
    fixed = kink_corrected(x, switches)
    assert (fixed is not None) == corrected
    if corrected:
        k = np.flatnonzero(switches)[3]
        assert fixed[k] - x[k] == pytest.approx((x[k + 1] - 2 * x[k] + x[k - 1]) / 12)
        assert np.array_equal(fixed[~switches], x[~switches])


def _first_order_record(hold: str, seed: int, rate: float = 2.0) -> dict:
    """``x' = -rate x + 1.5 rate u`` (default ``-2 x + 3 u``) under a PRBS of 5-sample bits applied
    with zero-order hold, sampled exactly (the hold's exact discretisation), x measured without noise."""
    rng = np.random.default_rng(seed)
    dt, n = 0.02, 2000
    u = np.repeat(rng.choice([-1.0, 1.0], n // 5 + 1), 5)[:n]
    decay = np.exp(-rate * dt)  # x_{k+1} = decay x_k + (1 - decay) (3 / 2) u_k, exact under the hold
    x = np.empty(n)
    x[0] = 0.5
    for k in range(n - 1):
        x[k + 1] = decay * x[k] + (1 - decay) * 1.5 * u[k]
    return {"t": np.arange(n) * dt, "x": x, "u": u}


@pytest.mark.parametrize("hold, error", [("auto", 0.003), ("linear", None)])
def test_held_input_gives_the_true_theta_where_linear_interpolation_biases_it(hold, error):
    model = {"states": ["x"], "inputs": ["u"], "parameters": {"a": 1.8, "b": 3.3},
             "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "-a"}, {"term": "u", "theta": "b"}],
                            "adjustments": ["abs(x)"]}]}
    config = {"model": model, "data": {"time": "t", "columns": {"x": "x", "u": "u"}, "input_hold": hold}}
    report = diagnose(config, data=_first_order_record(hold, 0), validation=_first_order_record(hold, 1), options=QUICK)
    gap = report.equations[0]
    terms = gap.retuned_equation.split("=")[1].replace("- ", "-").replace("+ ", "").split()
    theta = dict(zip(terms[1::2], map(float, terms[0::2])))
    worst = max(abs(theta["x"] + 2.0) / 2.0, abs(theta["u"] - 3.0) / 3.0)
    if error is not None:
        assert gap.estimator["input_hold"] == {"u": "zoh"} and gap.estimator["kinks_corrected"] == ["x"]
        assert worst < error
    else:  # the samples of a held input read as a continuous signal: every switch half a sample late
        assert gap.estimator["input_hold"] == {"u": "linear"} and worst > 0.05
