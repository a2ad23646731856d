"""The weak form of Eq. 6 in ``adapt`` (``adaptation.form``): test functions from the band of the
signals the regressors read, and the strong form kept where the sampling does not resolve it."""
import math

import pandas as pd
import pytest
import torch

from msam_torch import adapt
from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.derivatives import SavitzkyGolay
from msam_torch.data.loading import Dataset
from msam_torch.data.systems import System, measure, multisine
from msam_torch.engine import weak_form as weak
from msam_torch.engine.weak_form import HALF_AMPLITUDE, SHORTEST, resolves
from msam_torch.run.estimation import choose, record_band, refined, regressor_band
from tests.run.test_estimator import CONFIG, PARAMETERS, quadratic_drag

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
    spec = to_spec(load_config({"model": MODEL}).model)
    position, _ = record_band({"t": t.numpy(), "q": q.numpy(), "tau": tau.numpy()}, spec.inputs)
    band, edges = regressor_band(spec, dataset)
    assert set(edges) == {"q", "q_dot"}  # neither the input nor the target
    assert band == edges["q_dot"] and band > 5 * position


def test_the_weak_form_needs_a_few_samples_per_test_function():
    assert resolves(HALF_AMPLITUDE / SHORTEST) and not resolves(1.01 * HALF_AMPLITUDE / SHORTEST)


@pytest.mark.slow
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


def test_refined_keeps_the_samples_and_interpolates_linearly_between_them():
    signal = torch.tensor([[0.0, 1.0, 3.0], [2.0, 2.0, -2.0]], dtype=torch.float64)
    fine = refined(signal, 4)
    assert fine.shape == (2, 9) and torch.equal(fine[..., ::4], signal)
    assert torch.allclose(fine[0], torch.tensor([0, 0.25, 0.5, 0.75, 1, 1.5, 2, 2.5, 3], dtype=torch.float64))
    assert refined(signal, 1) is signal


@pytest.mark.parametrize("function, coarse, linear, band_limited, cubic", [
    (torch.sign, (0.25, None), (None, 0.12), (None, 0.1), (None, 0.1)),  # where a speed reverses between samples
    (lambda x: x**3, (None, 0.002), (0.08, None), (None, 0.006), (None, 0.006)),  # smooth: linear interpolation distorts it
])
def test_sub_sample_quadrature(function, coarse, linear, band_limited, cubic):
    """A signal at 0.15 cycles per sample (two tones), test functions of 4 samples' half-width (its
    band edge's): the weak form of ``sign(x)`` on the samples misses where between them the sign
    switches (about 33 % error against a 64-fold quadrature of the signal itself); interpolated
    4-fold, 8-9 %. A smooth function of it the samples integrate within 0.1 %, linear interpolation
    distorts by about 13 %, band-limited interpolation keeps within 0.4 %."""
    def signal(t):
        return torch.sin(2 * math.pi * 0.15 * t + 0.4) + 0.5 * torch.sin(2 * math.pi * 0.0555 * t + 1.0)

    t = torch.arange(400, dtype=torch.float64)
    fine = refined(t, 64)
    truth = weak.TestFunctions.spanning(fine, 4.0).integrate_signal(function(signal(fine)))[5:-5]
    errors = {}
    for name, k, shape in (("coarse", 1, "linear"), ("linear", 4, "linear"), ("band_limited", 4, "band-limited"),
                           ("cubic", 4, "cubic")):
        rows = weak.TestFunctions.spanning(refined(t, k), 4.0).integrate_signal(function(refined(signal(t), k, shape)))
        assert rows.shape[0] == truth.shape[0] + 10  # the same test functions, on a finer grid
        errors[name] = float((rows[5:-5] - truth).norm() / truth.norm())
    for name, (low, high) in {"coarse": coarse, "linear": linear, "band_limited": band_limited, "cubic": cubic}.items():
        assert (low is None or errors[name] > low) and (high is None or errors[name] < high), (name, errors)


@pytest.mark.parametrize("held", [False, True])
@pytest.mark.parametrize("half_width, refine, samples, fold", [
    (5.0, True, 1000, 4), (1.0, True, 1000, 4), (8.0, True, 1000, 2), (32.0, True, 1000, 1), (4.0, False, 1000, 1),
    (5.0, True, 50, 2),  # 400 samples interpolated to at most 16 x 50
])
def test_the_diagnosis_interpolates_records_whose_half_width_holds_few_samples(half_width, refine, samples, fold,
                                                                               held):
    """k = ceil(16 samples / half-width), the half-width at least 4 samples (1.0 is raised to 4), the
    record at most 16 x ``samples`` long; band-limited, or where an input is held by local cubics
    (keeping the samples)."""
    t = torch.arange(400, dtype=torch.float64)
    q = torch.sin(0.3 * t)
    tau = torch.sign(torch.sin(0.05 * t)) if held else torch.cos(0.2 * t)
    dataset = Dataset({"t": t, "q": q, "q_dot": 0.3 * torch.cos(0.3 * t), "tau": tau})
    config = load_config({"model": MODEL})
    spec = to_spec(config.model)
    estimation = choose(spec, config.data, dataset, dataset, SavitzkyGolay(), half_width, samples, refine=refine)
    assert estimation.refinement == estimation.info["refinement"] == fold and estimation.decimation == 1
    for signals in (estimation.train, estimation.held_out):
        assert signals["t"].shape == ((400 - 1) * fold + 1,) and torch.equal(signals["t"][::fold], t)
        torch.testing.assert_close(signals["q"][::fold], q, rtol=0, atol=0 if held or fold == 1 else 2e-3)
    how = "by local cubics" if held else "band-limited"
    assert (f"interpolated {how}" in estimation.info["weak_form_signals"]) == (fold > 1)
    assert (f" {fold}-fold" in estimation.info["weak_form_signals"]) == (fold > 1)
