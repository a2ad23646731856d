"""The weak form of Eq. 6 in ``adapt`` (``adaptation.form``): test functions from the band of the
signals the regressors read, and the strong form kept where the sampling does not resolve it."""
import pandas as pd
import pytest
import torch

from msam_torch import adapt
from msam_torch.config import load_config
from msam_torch.data import Dataset
from msam_torch.estimation import record_band, regressor_band
from msam_torch.spec import ModelSpec
from msam_torch.systems import System, measure, multisine
from msam_torch.weak import HALF_AMPLITUDE, SHORTEST, resolves
from test_estimator import CONFIG, PARAMETERS, quadratic_drag

MODEL = {"states": ["q", "q_dot"], "inputs": ["tau"], "parameters": {"m": 1.0, "c": 1.0},
         "equations": [{"target": "q_ddot", "components": [{"term": "q_dot", "theta": "-c/m"},
                                                          {"term": "tau", "theta": "1/m", "adjustable": False}],
                        "adjustments": ["abs(q_dot)"]}]}


def test_the_regressors_band_reaches_a_velocitys_reversals():
    """A slow triangular position (0.1 cycles per time unit) has its power near the fundamental;
    its velocity, a square wave, has it in the odd harmonics: the regressors' band (of q and q_dot)
    lies well above the position's, which alone would ask for test functions blurring the reversals."""
    t = torch.arange(4000, dtype=torch.float64) * 0.01
    phase = (0.1 * t) % 1.0
    q = 4 * torch.abs(phase - 0.5) - 1
    q_dot = torch.where(phase < 0.5, -0.4, 0.4).to(torch.float64)
    tau = torch.sin(0.3 * t)
    dataset = Dataset({"t": t, "q": q, "q_dot": q_dot, "q_ddot": torch.zeros_like(t), "tau": tau}, {},
                      {"q": q, "tau": tau})
    spec = ModelSpec.from_config(load_config({"model": MODEL}).model)
    position, _ = record_band({"t": t.numpy(), "q": q.numpy(), "tau": tau.numpy()}, spec.inputs)
    band, edges = regressor_band(spec, dataset)
    assert set(edges) == {"q", "q_dot"}  # neither the input nor the target
    assert band == edges["q_dot"] and band > 5 * position


def test_the_weak_form_needs_a_few_samples_per_test_function():
    assert resolves(HALF_AMPLITUDE / SHORTEST) and not resolves(1.01 * HALF_AMPLITUDE / SHORTEST)


@pytest.mark.parametrize("sample_time, form", [(0.02, "weak"), (0.5, "strong")])
def test_auto_takes_the_weak_form_where_the_sampling_resolves_the_band(sample_time, form):
    """The drag oscillator at 50 samples per time unit, and at 2 (its response reaching 0.8 cycles
    per time unit, 0.4 per sample; derivatives by an interpolating spline, as for Silverbox):
    ``auto`` (the measured preset's) takes the weak form only for the first; ``weak`` forces it."""
    samples = 2000
    system = System(("x", "x_dot"), PARAMETERS, quadratic_drag, (0.0, 0.0), sample_time * (samples - 1), samples,
                    {"u": multisine((1, 2, 3, 4, 5), 4.0)}, ("x", "u"))
    s = {k: v.numpy() for k, v in measure(system, rtol=1e-7, atol=1e-9).items()}
    frame = pd.DataFrame({"time": s["t"], "x": s["x"], "u": s["u"]})
    quick = ["adaptation.round_robin_steps=2", "adaptation.refinement_steps=1", "data.derivatives=interpolating_spline"]
    result = adapt(CONFIG, quick, data=frame)
    assert result.config["adaptation"]["form"] == "auto" and result.data["form"] == form
    assert ("weak_form" in result.data) == (form == "weak")
    assert adapt(CONFIG, quick + ["adaptation.form=weak"], data=frame).data["form"] == "weak"
