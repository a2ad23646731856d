"""Loading, derivative estimation, held-out ranges and theta re-estimation."""
import numpy as np
import pytest
import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.derivatives import METHODS, choose_window, cutoff_frequency, estimate, noise_level
from msam_torch.data.systems import SYSTEMS, measure
from msam_torch.engine.candidates import EquationData
from msam_torch.engine.tuning import tune_adapted, tune_start
from msam_torch.errors import ConfigError, DataError
from msam_torch.run.adapt import adapt
from tests.helpers import QUICK, measured_case, simulated


@pytest.mark.parametrize("method, tolerance", [("savgol", 1e-3), ("spline", 2e-2), ("loess", 2e-2),
                                               ("finite_difference", 1e-3), ("butterworth", 1e-3),
                                               ("interpolating_spline", 1e-3)])
def test_estimators_recover_the_derivatives_of_a_smooth_signal(method, tolerance):
    t = np.linspace(0, 2 * np.pi, 800)
    values = estimate(t, np.sin(t), 2, method).values
    inner = slice(40, -40)  # edges are extrapolated by every method
    assert np.abs(values[1][inner] - np.cos(t[inner])).max() < tolerance * 10
    assert np.abs(values[2][inner] + np.sin(t[inner])).max() < tolerance * 100
    assert set(METHODS) == {"savgol", "spline", "loess", "finite_difference", "butterworth", "interpolating_spline"}


def test_butterworth_cutoff_follows_the_noise_floor_or_the_config():
    """Zero-phase Butterworth: the default cut-off is the noise-floor frequency (recorded), a given
    one is used as is (cycles per time unit), one at or above Nyquist is refused; on a noisy sine
    its acceleration is within 10 % of the amplitude, including the edges."""
    t = np.linspace(0, 2 * np.pi, 800)
    rng = np.random.default_rng(0)
    y = np.sin(t) + 1e-3 * rng.standard_normal(t.size)
    chosen = estimate(t, y, 2, "butterworth")
    assert chosen.info["window_rule"] == "noise floor" and chosen.info["filter_order"] == 4
    assert chosen.info["cutoff_per_sample"] == pytest.approx(cutoff_frequency(y, noise_level(y)))
    assert np.abs(chosen.values[2] + np.sin(t)).max() < 0.15
    given = estimate(t, y, 2, "butterworth", cutoff=2.0)
    assert given.info["cutoff"] == 2.0 and given.info["window_rule"] == "given"
    assert np.abs(given.values[2] + np.sin(t)).max() < 0.05
    with pytest.raises(DataError, match="data.cutoff=100 must lie between 0 and the Nyquist"):
        estimate(t, y, 2, "butterworth", cutoff=100.0)


def test_interpolating_spline_differentiates_near_the_nyquist_frequency():
    """Sines at 0.2 and 1/3 cycles per sample (a record whose content reaches a third of the sampling
    rate): the interpolating spline keeps both derivatives within 0.5 % and 6 %, where nested
    central differences lose 40 % and 80 % of the second derivative."""
    n = np.arange(3000)
    inner = slice(100, -100)
    for frequency, spline_error, difference_error in ((0.2, 5e-3, 0.4), (1 / 3, 0.06, 0.8)):
        w = 2 * np.pi * frequency
        exact = [np.sin(w * n + 0.3), w * np.cos(w * n + 0.3), -w * w * np.sin(w * n + 0.3)]
        relative = lambda values, k: np.linalg.norm(values[k][inner] - exact[k][inner]) / np.linalg.norm(exact[k][inner])
        spline = estimate(n * 1.0, exact[0], 2, "interpolating_spline").values
        assert relative(spline, 1) < spline_error and relative(spline, 2) < spline_error
        assert relative(estimate(n * 1.0, exact[0], 2, "finite_difference").values, 2) > difference_error


def test_noise_level_and_window_follow_the_noise():
    """A signal whose spectrum decays smoothly: more noise, lower cut-off, wider window."""
    t = np.linspace(0, 20, 2000)
    clean = 1 / (1 + (t - 10) ** 2) + 0.5 / (1 + 4 * (t - 6) ** 2)
    rng = np.random.default_rng(0)
    windows = []
    for sigma in (0.0, 1e-4, 1e-3, 1e-2, 1e-1):
        noisy = clean + sigma * rng.standard_normal(t.size)
        if sigma:
            assert noise_level(noisy) == pytest.approx(sigma, rel=0.15)
        windows.append(choose_window(noisy, 3)[0])
    assert windows == sorted(set(windows)) and windows[0] <= 7 and windows[-1] > 2 * windows[1], windows


def test_window_rule_beats_fixed_windows_on_the_oscillator():
    """The noise-floor window is within 2x of the best fixed window's error on x_ddot."""
    signals = simulated("harmonic")
    rng = np.random.default_rng(1)
    x = signals["x"] + 0.01 * signals["x"].std() * rng.standard_normal(signals["x"].size)
    error = lambda w: np.sqrt(np.mean((estimate(signals["t"], x, 2, "savgol", w).values[2] - signals["x_ddot"]) ** 2))
    chosen = estimate(signals["t"], x, 2, "savgol")
    best = min(error(w) for w in range(11, 302, 10))
    assert error(chosen.info["window"]) < 2 * best
    assert chosen.info["method"] == "savgol" and chosen.info["window_rule"].startswith("noise floor")


def test_butterworth_runs_from_a_config_and_is_recorded():
    """data.derivatives: butterworth with data.cutoff reaches the estimator and the result's provenance;
    a cut-off with another estimator is a config error naming data.cutoff."""
    config, frame = measured_case("harmonic", every=4)
    config["data"] = {"time": "t", "columns": {"x": "x", "u": "u"}, "derivatives": "butterworth", "cutoff": 2.0}
    info = adapt(config, QUICK, data=frame[["t", "x", "u"]]).data["derivatives"]["x"]
    assert info["method"] == "butterworth" and info["cutoff"] == 2.0 and info["window_rule"] == "given"
    with pytest.raises(ConfigError, match="data.cutoff"):
        adapt(config, QUICK + ["data.derivatives=savgol"], data=frame[["t", "x", "u"]])


def test_frame_and_tensor_inputs_give_the_file_result(tmp_path):
    config, frame = measured_case("harmonic", every=4)
    frame = frame[["t", "x", "u"]]
    config["data"] = {"time": "t", "columns": {"x": "pos", "u": "force"}, "derivatives": "savgol"}
    renamed = frame.rename(columns={"x": "pos", "u": "force"})
    renamed.to_csv(tmp_path / "data.csv", index=False)
    from_frame = adapt(config, QUICK, data=renamed)
    from_tensors = adapt(config, QUICK, data={c: torch.tensor(renamed[c].to_numpy()) for c in renamed})
    from_file = adapt({**config, "data": {**config["data"], "file": "data.csv"}}, QUICK, base_dir=tmp_path)
    assert from_frame.equations[0].exponents == from_tensors.equations[0].exponents == from_file.equations[0].exponents
    assert from_frame.data["derivatives"]["x"]["window"] == from_file.data["derivatives"]["x"]["window"]
    assert from_frame.data["source"].startswith("data frame") and "data.csv" in from_file.data["source"]


def test_ranges_by_time_and_index_and_held_out_measures(tmp_path):
    config, frame = measured_case("harmonic", every=2)
    config["data"].update(train={"stop": 2.0}, validation={"start": 2.0 + 1e-9})
    result = adapt(config, ["adaptation.theta=varpro"], data=frame)
    data = result.data
    assert data["samples"] == int((frame["t"] <= 2.0).sum()) and data["validation"]["samples"] == int((frame["t"] > 2.0).sum())
    held = result.equations[0].validation
    assert set(held) == {"start", "retuned", "adapted", "adapted_retuned"}
    assert held["adapted"]["sum_abs_error"] < 1e-6 * held["start"]["sum_abs_error"]  # the true form extrapolates
    config["data"].update(train={"start": 100, "stop": 299, "by": "index"}, validation=None)
    assert adapt(config, QUICK, data=frame).data["samples"] == 200


def test_theta_re_estimation_recovers_the_true_theta_and_reveals_the_nominal_error():
    config = load_config("configs/harmonic.yaml")
    spec = to_spec(config.model)
    eq = spec.equations[0]
    data = EquationData.build(eq, measure(SYSTEMS["harmonic"]))
    true = spec.theta(eq)
    choice, gamma = torch.tensor([[0, 1]]), torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    tuned = tune_adapted(data, choice, gamma, true[[2]].unsqueeze(0))
    assert torch.allclose(tuned.theta[0], true[:2], rtol=1e-9) and torch.allclose(tuned.theta_fixed[0], true[2:], rtol=1e-9)
    held = tune_adapted(data, choice, gamma, 2 * true[[2]].unsqueeze(0), hold_fixed=True)
    assert torch.equal(held.theta_fixed[0], 2 * true[2:])  # held at the given value
    start = tune_start(data, true[[2]].unsqueeze(0))
    assert start.measures["sum_abs_error"] < EquationData.build(eq, measure(SYSTEMS["harmonic"])).y.abs().sum()
    result = adapt("configs/harmonic.yaml", ["adaptation.theta=varpro", "data.parametric_error=1.0", "data.seed=2"])
    tuning = result.equations[0].theta_tuning
    nominal = spec.theta(eq, result.data["nominal_parameters"])
    expected = ((nominal - true).abs() / true.abs()).tolist()
    assert tuning["adapted_retuned"]["nominal_error"] == pytest.approx(expected, rel=1e-6)
    assert tuning["adapted_retuned"]["theta"] == pytest.approx(true.tolist(), rel=1e-6)


def test_tuned_start_is_used_when_asked():
    plain = adapt("configs/harmonic.yaml", QUICK + ["data.parametric_error=1.0"])
    tuned = adapt("configs/harmonic.yaml", QUICK + ["data.parametric_error=1.0", "adaptation.tune_theta=true"])
    a, b = plain.equations[0], tuned.equations[0]
    assert a.theta_tuning["retuned"]["theta"] == pytest.approx(b.theta_tuning["retuned"]["theta"])
    assert b.start["sum_abs_error"] == pytest.approx(b.theta_tuning["retuned"]["sum_abs_error"])
    assert b.start_equation == b.theta_tuning["retuned"]["equation"] != a.start_equation


def test_parquet_files_load_like_csv(tmp_path):
    """The same record as CSV and as Parquet gives identical signals."""
    import numpy as np
    import pandas as pd

    from msam_torch.config.schema import load_config
    from msam_torch.data.loading import load_datasets

    t = np.linspace(0.0, 2.0, 201)
    frame = pd.DataFrame({"time": t, "pos": np.sin(3 * t), "force": np.cos(t)})
    frame.to_csv(tmp_path / "r.csv", index=False)
    frame.to_parquet(tmp_path / "r.parquet")
    model = {"states": ["x", "x_dot"], "inputs": ["u"], "parameters": {"k": 9.0},
             "equations": [{"target": "x_ddot", "components": [{"term": "x", "theta": "-k"},
                                                                {"term": "u", "theta": 1, "adjustable": False}],
                            "adjustments": ["abs(x)"]}]}
    loaded = []
    for name in ("r.csv", "r.parquet"):
        config = load_config({"model": model, "data": {"file": name, "time": "time", "derivatives": "savgol",
                                                       "columns": {"x": "pos", "u": "force"}}})
        train, _ = load_datasets(config.data, to_spec(config.model), tmp_path)
        loaded.append(train.signals)
    assert set(loaded[0]) == set(loaded[1]) >= {"x", "x_ddot", "u"}
    for name in loaded[0]:
        assert (loaded[0][name] == loaded[1][name]).all(), name


def test_noise_level_reads_no_noise_in_a_noise_free_kinked_state():
    """A first-order state under a PRBS held for 8 samples (relaxing at 0.3 per sample): its third
    differences alone read 0.24 % of its spread as noise, the least over the orders 3-8 reads none;
    with 1 % white noise added, the estimate is within 25 % of it."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.choice([-1.0, 1.0], size=251), 8)[:2000]
    x = np.zeros(2000)
    for j in range(1, 2000):
        x[j] = x[j - 1] * np.exp(-0.3) + u[j - 1] * (1 - np.exp(-0.3))
    third = np.diff(x, 3)
    assert np.median(np.abs(third - np.median(third))) * 1.4826 / np.sqrt(20) > 1e-3 * x.std()
    assert noise_level(x) < 1e-5 * x.std()
    sigma = 0.01 * x.std()
    assert noise_level(x + sigma * rng.standard_normal(x.size)) == pytest.approx(sigma, rel=0.25)
