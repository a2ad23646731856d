"""Inputs held between samples (zero-order hold) in the weak form (msam_torch.data.hold)."""
import numpy as np
import pytest
import torch
from numpy.polynomial import polynomial as P
from scipy.integrate import solve_ivp

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.hold import SAMPLED, hermite, is_held, quadrature_values, represent
from msam_torch.diagnosis import DiagnoseOptions, diagnose
from msam_torch.run.estimation import kinking, refined, refitted
from msam_torch.zoo import excitation
from tests.helpers import ONE_STEP


def test_a_held_input_is_told_from_a_sampled_continuous_one():
    rng = np.random.default_rng(0)
    prbs = np.repeat(rng.choice([-1.0, 1.0], 400), 3)  # bits of 3 samples
    assert is_held(prbs)
    assert not is_held(np.sin(0.05 * np.arange(1200)))
    assert not is_held(np.ones(100))  # a constant has no intersample behaviour to tell
    assert quadrature_values(np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])).tolist() == pytest.approx(
        [0.0, 0.0, -1 / 24, 0.5, 25 / 24, 1.0])
    signals, behaviour, _, _ = represent({"t": np.arange(1200.0), "u": prbs, "x": prbs}, ["u"], "auto")
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


@pytest.mark.parametrize("rate, noise", [(2.0, 0.0), (25.0, 0.0), (50.0, 0.0), (25.0, 0.05), (150.0, 0.0)])
def test_kinks_are_corrected_from_the_starting_models_jump(rate, noise):
    """``x' = -rate x + 1.5 rate u`` under a PRBS of 5-sample bits (``r = dt rate`` from 0.04 to 3):
    each switch sample moves by ``dt [x'] rho(r) / 12``, the jump and the slope the starting model's
    (nominal parameters 10 % off), and the trapezoid rule on ``x^2`` over the record loses at least
    four times less than uncorrected, noise or not (the jump is not read from the samples);
    a state that settles within half a sample (``r > 2``) is left as it is."""
    record = _first_order_record("zoh", 0, rate)
    model = {"states": ["x"], "inputs": ["u"], "parameters": {"a": 1.1 * rate, "b": 0.9 * 1.5 * rate},
             "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "-a"}, {"term": "u", "theta": "b"}],
                            "adjustments": ["abs(x)"]}]}
    kinks = kinking(to_spec(load_config({"model": model}).model))
    x = record["x"] + noise * np.random.default_rng(1).standard_normal(record["x"].size)
    out, _, corrected, _ = represent({**record, "x": x}, ["u"], "zoh", kinks)
    switches = np.flatnonzero(np.diff(record["u"], prepend=record["u"][:1]) != 0)
    dt, r = 0.02, 0.02 * 1.1 * rate
    if r > SAMPLED:
        assert corrected == [] and np.array_equal(out["x"], x)
        return
    assert corrected == ["x"] and np.array_equal(np.delete(out["x"], switches), np.delete(x, switches))
    k = switches[3]
    rho = 12 * ((r / 2) / np.tanh(r / 2) - 1) / r**2
    assert out["x"][k] - x[k] == pytest.approx(dt * 0.9 * 1.5 * rate * (record["u"][k] - record["u"][k - 1]) * rho / 12)
    if noise == 0:  # the exact integral of x^2, cell by cell under the hold, against the trapezoid rule
        u, samples = record["u"], record["x"]
        decay, target = np.exp(-rate * dt), 1.5 * u[:-1]
        d = samples[:-1] - target
        exact = np.sum(target**2 * dt + 2 * target * d * (1 - decay) / rate + d**2 * (1 - decay**2) / (2 * rate))
        trapezoid = lambda v: dt * (np.sum(v**2) - (v[0] ** 2 + v[-1] ** 2) / 2)
        assert abs(trapezoid(out["x"]) - exact) < abs(trapezoid(samples) - exact) / 4


@pytest.mark.parametrize("rate, tolerance", [(2.0, 0.002), (25.0, 0.005), (50.0, 0.02)])
def test_kinks_take_their_jump_from_the_starting_model_refitted_to_the_record(rate, tolerance):
    """Nominal coefficients 20 % off (``x' = -0.8 rate x + 1.8 rate u`` for ``-rate x + 1.5 rate u``):
    the starting model re-fitted in the weak form to the record corrected with its nominal jumps
    (:func:`~msam_torch.run.estimation.refitted`) is within ``tolerance`` of the truth, and its jumps
    leave at least five times less of the trapezoid rule's error on ``x^2`` than the nominal ones."""
    record = _first_order_record("zoh", 0, rate)
    model = {"states": ["x"], "inputs": ["u"], "parameters": {"a": 0.8 * rate, "b": 1.2 * 1.5 * rate},
             "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "-a"}, {"term": "u", "theta": "b"}],
                            "adjustments": ["abs(x)"]}]}
    spec = to_spec(load_config({"model": model}).model)
    nominal, _, _, _ = represent(record, ["u"], "zoh", kinking(spec))
    signals = {**{k: torch.tensor(v) for k, v in nominal.items()}, "x_dot": torch.zeros(len(nominal["x"]), dtype=torch.float64)}
    theta = refitted(kinking(spec), signals, 10 * 0.02)  # the weak form reads no x_dot: a placeholder
    assert theta["x_dot"].numpy() == pytest.approx([-rate, 1.5 * rate], rel=tolerance)
    again, _, _, _ = represent(record, ["u"], "zoh", kinking(spec, theta))
    dt, u, samples = 0.02, record["u"], record["x"]
    decay, target = np.exp(-rate * dt), 1.5 * u[:-1]
    d = samples[:-1] - target
    exact = np.sum(target**2 * dt + 2 * target * d * (1 - decay) / rate + d**2 * (1 - decay**2) / (2 * rate))
    trapezoid = lambda v: dt * (np.sum(v**2) - (v[0] ** 2 + v[-1] ** 2) / 2)
    assert abs(trapezoid(again["x"]) - exact) < abs(trapezoid(nominal["x"]) - exact) / 5


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
    report = diagnose(config, data=_first_order_record(hold, 0), validation=_first_order_record(hold, 1), options=ONE_STEP)
    gap = report.equations[0]
    terms = gap.retuned_equation.split("=")[1].replace("- ", "-").replace("+ ", "").split()
    theta = dict(zip(terms[1::2], map(float, terms[0::2])))
    worst = max(abs(theta["x"] + 2.0) / 2.0, abs(theta["u"] - 3.0) / 3.0)
    if error is not None:
        assert gap.estimator["input_hold"] == {"u": "zoh"} and gap.estimator["kinks_corrected"] == ["x"]
        assert worst < error
    else:  # the samples of a held input read as a continuous signal: every switch half a sample late
        assert gap.estimator["input_hold"] == {"u": "linear"} and worst > 0.05


@pytest.mark.parametrize("rate", [5.0, 25.0, 75.0])
def test_a_kinking_state_follows_the_starting_models_rates_between_samples(rate):
    """``x' = -rate x + 1.5 rate u`` under a PRBS (``r`` = 0.1, 0.5, 1.5 per sample), the starting
    model's coefficients 10 % off, test functions of 4 samples' half-width, the record interpolated
    4-fold: along the cubics with the model's rates at either end of each cell
    (:func:`~msam_torch.data.hold.hermite`), the weak form of ``x^2`` is within 0.5 % of the exact one
    (the hold's exact solution 256-fold between samples; 0.01 %, 0.06 %, 0.4 %), at least ten times
    closer than the kink-corrected samples interpolated linearly (0.5 %, 1.9 %, 4.8 %: the
    correction is made for the trapezoid rule on the samples, not for a line between them)."""
    record = _first_order_record("zoh", 0, rate)
    model = {"states": ["x"], "inputs": ["u"], "parameters": {"a": 1.1 * rate, "b": 0.9 * 1.5 * rate},
             "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "-a"}, {"term": "u", "theta": "b"}],
                            "adjustments": ["abs(x)"]}]}
    out, _, _, sides = represent(record, ["u"], "zoh", kinking(to_spec(load_config({"model": model}).model)))
    dt, x, u = 0.02, record["x"], record["u"]

    def exact(k):  # the hold's solution: x relaxes to 1.5 u over each cell
        s = np.arange(k) / k
        cells = 1.5 * u[:-1, None] + (x[:-1, None] - 1.5 * u[:-1, None]) * np.exp(-rate * dt * s)
        return np.concatenate([cells.ravel(), x[-1:]])

    def rows(fine, k, half_width=4):  # bump test functions of half_width samples, every 7th sample
        s = np.linspace(-1.0, 1.0, 2 * half_width * k + 1)
        phi = (1 - s**2) ** 4 * dt / k
        return np.array([fine[c * k - half_width * k:c * k + half_width * k + 1] @ phi for c in range(50, x.size - 50, 7)])

    truth = rows(exact(256) ** 2, 256)
    error = lambda fine: np.linalg.norm(rows(fine**2, 4) - truth) / np.linalg.norm(truth)
    along = error(hermite(sides["x"], 4, dt))
    assert along < 0.005 and along < error(refined(torch.tensor(out["x"]), 4).numpy()) / 10


def test_local_cubics_are_exact_on_cubics_and_a_kink_bends_only_its_neighbours():
    """Between samples, :func:`~msam_torch.data.hold.local_cubic` reproduces a cubic polynomial (away from
    the record's ends, where the reflection is not exact), keeps every sample, and a kink (``|t|``)
    moves the interpolant only in the two cells either side of it, where a cubic spline's error
    spreads through the record."""
    from scipy.interpolate import CubicSpline

    from msam_torch.data.hold import local_cubic
    t = np.arange(40.0)
    cubic = 0.01 * t**3 - 0.3 * t**2 + t - 2.0
    fine = local_cubic(cubic, 4)
    tf = np.arange(fine.size) / 4
    assert np.allclose(fine[8:-8], (0.01 * tf**3 - 0.3 * tf**2 + tf - 2.0)[8:-8], rtol=0, atol=1e-10)
    assert np.array_equal(fine[::4], cubic)
    kink = np.abs(t - 20.0)
    error = np.abs(local_cubic(kink, 4) - np.abs(tf - 20.0))
    assert error[:4 * 18].max() < 1e-12 and error[4 * 22:].max() < 1e-12 and error.max() > 0.01
    spline = np.abs(CubicSpline(t, kink)(tf) - np.abs(tf - 20.0))
    assert spline[:4 * 14].max() > 1e-5


def test_a_motor_whose_current_settles_within_two_samples_gives_its_drag_law():
    """A DC motor (``i' = -a i - k w + b u``, ``w' = K i - c w - d w|w|``) whose current relaxes
    within 1.25 samples, driven by a PRBS held over its samples, recorded exactly; its damping is a
    small part of the speed's rate. Test functions of 4 samples' half-width, the record
    interpolated 4-fold: least squares on the weak form of the speed's equation with the true terms
    gives ``c`` and ``d`` within 1 % along the current's cubics (the starting model 10 % off) and
    local cubics of the speed, ten times closer than linear interpolation of the kink-corrected
    samples (``d`` 5 % off: the line shows the current through a wider test function than the
    speed's weak form)."""
    from scipy.integrate import solve_ivp

    from msam_torch.data.derivatives import SavitzkyGolay
    from msam_torch.data.loading import Dataset
    from msam_torch.engine.weak_form import TestFunctions
    from msam_torch.run.estimation import choose

    dt, n, a, k, b, K, c, d = 0.01, 2000, 80.0, 0.5, 60.0, 200.0, 0.5, 0.002
    u = np.repeat(np.random.default_rng(2).choice([-1.0, 1.0], n // 6 + 1), 6)[:n]
    x, states = np.zeros(2), [np.zeros(2)]
    for m in range(n - 1):  # the held input over each cell, integrated to round-off
        x = solve_ivp(lambda _, s: [-a * s[0] - k * s[1] + b * u[m], K * s[0] - c * s[1] - d * s[1] * abs(s[1])],
                      (0.0, dt), x, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        states.append(x)
    i, w = np.array(states).T
    model = {"states": ["i", "w"], "inputs": ["u"], "parameters": {"a": 1.1 * a, "k": 0.9 * k, "b": 1.1 * b, "K": K, "c": c},
             "equations": [{"target": "i_dot", "components": [{"term": "i", "theta": "-a"}, {"term": "w", "theta": "-k"},
                                                             {"term": "u", "theta": "b"}], "adjustments": ["abs(i)"]},
                           {"target": "w_dot", "components": [{"term": "i", "theta": "K"}, {"term": "w", "theta": "-c"}],
                            "adjustments": ["abs(w)"]}]}
    config = load_config({"model": model, "data": {"time": "t", "columns": {"i": "i", "w": "w", "u": "u"}}})
    spec = to_spec(config.model)
    t = torch.arange(n, dtype=torch.float64) * dt
    signals = {"t": t, "i": torch.tensor(i), "w": torch.tensor(w), "u": torch.tensor(u)}
    record = Dataset(signals, measured={name: v for name, v in signals.items() if name != "t"})
    estimation = choose(spec, config.data, record, None, SavitzkyGolay(), 4 * dt, refine=True)
    assert estimation.refinement == 4 and estimation.info["kinks_corrected"] == ["i"]

    def damping_error(s):
        tests = TestFunctions.spanning(s["t"], 4 * dt)
        y = -tests.integrate_signal(s["w"], 1)
        rows = torch.stack([tests.integrate_signal(v) for v in (s["i"], s["w"], s["w"] * s["w"].abs())], -1)
        fitted = torch.linalg.lstsq(rows, y.unsqueeze(-1)).solution.squeeze(-1)
        return max(abs(float(-fitted[1]) / c - 1), abs(float(-fitted[2]) / d - 1))

    corrected = represent({"t": t.numpy(), "i": i, "w": w, "u": u}, ["u"], "zoh", kinking(spec))[0]["i"]
    linear = {**estimation.train, "i": refined(torch.as_tensor(corrected), 4), "w": refined(torch.tensor(w), 4)}
    along = damping_error(estimation.train)
    assert along < 0.01 and along < damping_error(linear) / 10


def test_a_held_out_record_is_run_under_its_own_hold():
    """Training under a smooth multisine (read as sampled), the held-out record under a held PRBS:
    the held-out free run holds the PRBS as the weak form reads it, at steps that meet every switch,
    so the exact starting model reproduces the record; read linearly (the training record's
    behaviour), every switch would be half a sample late."""
    dt, n = 0.02, 2000
    t = np.arange(n) * dt
    u = lambda s: np.sin(1.3 * s) + 0.5 * np.sin(3.1 * s + 1.0)
    x = solve_ivp(lambda s, y: -2.0 * y + 3.0 * u(s), (0.0, t[-1]), [0.5], t_eval=t, rtol=1e-10, atol=1e-12).y[0]
    model = {"states": ["x"], "inputs": ["u"], "parameters": {"a": 2.0, "b": 3.0},
             "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "-a"}, {"term": "u", "theta": "b"}],
                            "adjustments": ["abs(x)"]}]}
    config = {"model": model, "data": {"time": "t", "columns": {"x": "x", "u": "u"}}}
    options = DiagnoseOptions(bootstrap=0, steps=20, max_effects=1)
    report = diagnose(config, data={"t": t, "x": x, "u": u(t)}, validation=_first_order_record("auto", 1), options=options)
    estimator = report.equations[0].estimator
    assert estimator["input_hold"] == {"u": "linear"} and estimator["held_out_input_hold"] == {"u": "zoh"}
    free_run = report.measures["free_run"]
    # 0.16 % and 0.28 % (both starting from the decimated record's first sample); read linearly 12 %
    assert free_run["train"]["nrmse"]["start"] < 0.005 and free_run["held_out"]["nrmse"]["start"] < 0.005
