"""Simulation mode reads its records through the project's one loader: in-memory tables given to
``adapt`` and ``diagnose`` are used, every ``data.derivatives`` value works, and a
trainer factory is honoured."""
import copy

import numpy as np
import pandas as pd
import pytest
import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import Dataset
from msam_torch.diagnosis import diagnose
from msam_torch.errors import ConfigError
from msam_torch.run.adapt import adapt, make_trainer
from msam_torch.simulation.configured import load_records, output_states
from msam_torch.simulation.ode import build_model
from tests.simulation.test_simulation_mode import TANKS, torricelli_record

SHORT = ["adaptation.round_robin_steps=2", "adaptation.refinement_steps=1", "adaptation.simulation.prefit_steps=4"]


def at_true_exponents() -> dict:
    raw = copy.deepcopy(TANKS)
    raw["data"]["file"] = "absent.csv"  # only the in-memory tables can be read
    for equation in raw["model"]["equations"]:
        for component in equation["components"]:
            if component.get("adjustable", True):
                component["start"] = -0.5
    return raw


def test_adapt_uses_a_data_frame_and_the_trainer_factory(tmp_path):
    torricelli_record(tmp_path / "tanks.csv", n=40)
    frame = pd.read_csv(tmp_path / "tanks.csv")
    from_file = adapt(TANKS, SHORT, base_dir=tmp_path)
    built = []
    factory = lambda config: built.append(make_trainer(config)) or built[-1]
    from_frame = adapt(at_true_exponents() | {"model": TANKS["model"]}, SHORT, base_dir=tmp_path, data=frame,
                       trainer_factory=factory)
    assert len(built) == 1 and from_frame.data["source"] == "data frame"
    for a, b in zip(from_file.equations, from_frame.equations):
        assert a.equation == b.equation
        assert a.adapted["fitness"] == pytest.approx(b.adapted["fitness"], rel=1e-12)
    with pytest.raises(ConfigError, match="trainer_factory"):
        adapt(TANKS, SHORT, base_dir=tmp_path, trainer_factory=lambda config: object())


@pytest.mark.parametrize("derivatives", ["auto", "savgol", "interpolating_spline", "butterworth", "exact"])
def test_every_derivative_estimator_gives_the_initial_velocity(derivatives):
    """An oscillator measured by its position only: x_dot(0) (the start of the simulation) from the
    configured estimator; ``exact`` has nothing to estimate it from and says so."""
    t = np.linspace(0.0, 10.0, 501)
    frame = pd.DataFrame({"t": t, "x": np.sin(t) + 0.1 * t})  # x_dot(0) = 1.1
    config = load_config({
        "model": {"states": ["x", "x_dot"], "parameters": {"k": 1.0},
                  "equations": [{"target": "x_ddot", "components": [{"term": "x", "theta": "-k"}],
                                 "adjustments": ["abs(x)"]}]},
        "data": {"time": "t", "columns": {"x": "x"}, "derivatives": derivatives},
        "adaptation": {"evaluation": "simulation", "simulation": {"output": ["x"]}}})
    spec = to_spec(config.model)
    model = build_model(spec, spec.equations)
    load = lambda: load_records(config, spec, model, output_states(config, spec, model), ".", data=frame)
    if derivatives == "exact":
        with pytest.raises(ConfigError, match="data.derivatives"):
            load()
        return
    record, validation = load()
    assert validation is None
    torch.testing.assert_close(record.outputs[0], torch.as_tensor(frame["x"].to_numpy().copy()))  # as measured
    assert float(record.guess[0]) == 0.0 and abs(float(record.guess[1]) - 1.1) < 0.02


def test_diagnose_in_simulation_mode_uses_in_memory_training_and_validation_tables(tmp_path):
    """Two tanks at the true exponents, the records given as a DataFrame and a mapping of arrays
    (the config's file does not exist): the held-out free run is the validation table's."""
    torricelli_record(tmp_path / "train.csv", n=60)
    train = pd.read_csv(tmp_path / "train.csv")
    held = {k: v[20:].to_numpy() for k, v in train.items()}
    held["t"] = held["t"] - held["t"][0]
    config = load_config(at_true_exponents(), SHORT + ["adaptation.damping=0.01"])
    report = diagnose(config, data=train, validation=held, base_dir=tmp_path)
    assert report.data["held_out"] == "validation record" and report.data["train"] == "data frame"
    free_run = report.measures["free_run"]["held_out"]
    assert free_run["nrmse"]["adapted"] < 0.2 * free_run["nrmse"]["retuned"]
    samples = len(report.series["x2_dot"]["free_run_held_out"]["t"])
    assert samples == 40


def test_a_dataset_a_mapping_and_a_path_give_the_record_of_the_config_file(tmp_path):
    torricelli_record(tmp_path / "tanks.csv", n=30)
    frame = pd.read_csv(tmp_path / "tanks.csv")
    config = load_config(TANKS)
    spec = to_spec(config.model)
    model = build_model(spec, spec.equations)
    outputs = output_states(config, spec, model)
    load = lambda data=None: load_records(config, spec, model, outputs, tmp_path, data=data)[0]
    reference = load()
    signals = {name: torch.tensor(frame[column].to_numpy()) for name, column in (("t", "t"), ("u", "u"), ("x2", "y"))}
    for data in (Dataset(signals), {k: v.to_numpy() for k, v in frame.items()}, tmp_path / "tanks.csv"):
        record = load(data)
        for name in ("t", "external", "outputs", "guess"):
            torch.testing.assert_close(getattr(record, name), getattr(reference, name), rtol=0, atol=0)
    assert reference.outputs.shape == (1, 30) and reference.guess.tolist() == [3.0, float(frame["y"][0])]


@pytest.mark.parametrize("power, verdict", [(1.0, "no significant gap"), (0.5, "inconclusive")])
def test_no_gap_by_simulation_needs_a_residual_that_looks_like_noise(tmp_path, power, verdict):
    """Two tanks with linear (``power`` 1) or square-root outflow, the lower level measured with
    1 % white noise, a linear starting model whose only candidate adjustments (powers of the input)
    cannot express the outflow law: on linear tanks the re-fitted start's held-out free-run residual
    is white and the verdict is "no significant gap"; on square-root tanks it is autocorrelated, so
    the verdict is "inconclusive" and says why."""
    torricelli_record(tmp_path / "tanks.csv", n=150, power=power)
    frame = pd.read_csv(tmp_path / "tanks.csv")
    frame["y"] += 0.01 * frame["y"].std() * np.random.default_rng(1).standard_normal(len(frame))
    train, held = frame[:100], frame[100:].assign(t=lambda f: f["t"] - f["t"].iloc[0])
    config = copy.deepcopy(TANKS)
    for equation in config["model"]["equations"]:
        equation["adjustments"] = ["abs(u)"]
    report = diagnose(load_config(config, SHORT), data=train, validation=held, base_dir=tmp_path)
    checks = report.equations[1].checks
    assert report.verdict.split(";")[0] == verdict, report.reasons
    if power == 0.5:
        assert checks["ljung_box_p"] < 1e-6 and any("autocorrelated" in r for r in report.reasons), checks
        assert not any("--half-width" in r for r in report.reasons)  # no test functions by simulation
    else:
        assert checks["ljung_box_p"] > 0.01 and checks["failed"] == [] and report.reasons == (), checks
