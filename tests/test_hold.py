"""Inputs held between samples (zero-order hold) in the weak form (msam_torch.hold)."""
import numpy as np
import pytest

from msam_torch.diagnose import DiagnoseOptions, diagnose
from msam_torch.hold import cell_averages, is_held, represent
from msam_torch.zoo import excitation

QUICK = DiagnoseOptions(bootstrap=0, steps=20, free_run=False, max_effects=1)


def test_a_held_input_is_told_from_a_sampled_continuous_one():
    rng = np.random.default_rng(0)
    prbs = np.repeat(rng.choice([-1.0, 1.0], 400), 3)  # bits of 3 samples
    assert is_held(prbs)
    assert not is_held(np.sin(0.05 * np.arange(1200)))
    assert not is_held(np.ones(100))  # a constant has no intersample behaviour to tell
    assert cell_averages(np.array([0.0, 0.0, 1.0, 1.0])).tolist() == [0.0, 0.0, 0.5, 1.0]
    signals, behaviour = represent({"t": np.arange(1200.0), "u": prbs, "x": prbs}, ["u"], "auto")
    assert behaviour == {"u": "zoh"} and signals["u"][3] == 0.5 * (prbs[2] + prbs[3]) and signals["x"] is prbs
    assert represent({"u": prbs}, ["u"], "linear")[1] == {"u": "linear"}


def test_zoo_steps_and_prbs_switch_only_at_sampling_instants():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 100.0, 8 * 1000 + 1)  # the zoo's dense grid: 8 points per sample of 0.1
    for kind in ("steps", "prbs"):
        e, _ = excitation.draw(rng, t, 10.0, kind, fraction=0.2)
        switches = np.flatnonzero(np.diff(e)) + 1
        assert switches.size > 10 and np.all(switches % 8 == 0)


def _first_order_record(hold: str, seed: int) -> dict:
    """``x' = -2 x + 3 u`` under a PRBS of 5-sample bits applied with zero-order hold, sampled
    exactly (the hold's exact discretisation), x measured without noise."""
    rng = np.random.default_rng(seed)
    dt, n = 0.02, 2000
    u = np.repeat(rng.choice([-1.0, 1.0], n // 5 + 1), 5)[:n]
    decay = np.exp(-2.0 * dt)  # x_{k+1} = decay x_k + (1 - decay) (3 / 2) u_k, exact under the hold
    x = np.empty(n)
    x[0] = 0.5
    for k in range(n - 1):
        x[k + 1] = decay * x[k] + (1 - decay) * 1.5 * u[k]
    return {"t": np.arange(n) * dt, "x": x, "u": u}


@pytest.mark.parametrize("hold, error", [("auto", 0.02), ("linear", None)])
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
        assert gap.estimator["input_hold"] == {"u": "zoh"} and worst < error
    else:  # the samples of a held input read as a continuous signal: every switch half a sample late
        assert gap.estimator["input_hold"] == {"u": "linear"} and worst > 0.05
