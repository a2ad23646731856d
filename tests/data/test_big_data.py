"""Records sampled far faster than their band (issue 18, large records): decimated before anything
else reads them, the band kept, the decision recorded, and the diagnosis unchanged.
``python -m experiments.bench.big_csv`` runs the 3.5 M-row case and prints its time and memory."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from msam_torch.config.schema import load_config
from msam_torch.data.bandwidth import RESOLVED, decimate, oversampling
from msam_torch.data.loading import load_datasets
from msam_torch.data.systems import WITHHELD
from msam_torch.data.withheld import finer_records
from msam_torch.diagnosis import diagnose
from msam_torch.run.plan import prepare

DATASETS = Path(__file__).resolve().parents[2] / "msam_torch" / "data" / "datasets"


def sine_record(per_period: int, periods: int = 20, noise: float = 0.01, seed: int = 0):
    n = per_period * periods
    t = np.arange(n) / per_period
    clean = np.sin(2 * np.pi * t) + 0.5 * np.cos(2 * np.pi * 0.3 * t + 1.0)
    return t, clean, clean + noise * np.random.default_rng(seed).standard_normal(n)


def test_an_oversampled_record_keeps_its_band_and_its_ends():
    t, clean, noisy = sine_record(per_period=2000, periods=100)
    every, band = oversampling({"y": noisy})
    assert band == pytest.approx(1 / 2000, rel=0.15)  # the 1-cycle-per-period sine is the edge
    assert every == pytest.approx(2000 / RESOLVED, rel=0.15)
    kept = decimate(noisy, every)
    assert kept.size == t[::every].size
    error = kept - clean[::every]
    assert np.sqrt(np.mean(error**2)) < 0.01 / 3  # the band kept, the noise above it averaged away
    assert abs(error[0]) < 0.01 and abs(error[-1]) < 0.01  # the ends keep their level (no zero padding)


@pytest.mark.parametrize("per_period", [25, 150])
def test_a_record_of_up_to_200_samples_per_period_is_not_decimated(per_period):
    assert oversampling({"y": sine_record(per_period)[2]})[0] == 1


@pytest.mark.parametrize("path, columns", [("emps/emps_estimation.csv.gz", ["qm_m", "force_N"]),
                                           ("silverbox/multisine.csv.gz", ["V2", "V1"]),
                                           ("cascaded_tanks/estimation.csv", ["y_V", "u_V"])])
def test_bundled_records_are_not_decimated(path, columns):
    frame = pd.read_csv(DATASETS / path, comment="#")
    assert oversampling({c: frame[c].to_numpy(float) for c in columns})[0] == 1


def test_the_loader_decimates_an_oversampled_record_and_records_it():
    t, _, x = sine_record(per_period=2000, periods=100)
    frame = pd.DataFrame({"t": t, "x": x})
    config = load_config({"model": {"states": ["x"], "equations": [
        {"target": "x_dot", "components": [{"term": "x", "theta": -1.0}], "adjustments": ["abs(x)"]}]},
        "data": {"time": "t", "columns": {"x": "x"}, "validation": {"start": 80.0}, "train": {"stop": 80.0}}})
    plan = prepare(config, in_memory=True)
    train, held_out = load_datasets(config.data, plan.spec, frame=frame, estimator=plan.derivatives)
    info = train.info["decimated"]
    assert info["from"] == 160_001 and info["factor"] == pytest.approx(20, abs=3)
    assert info["to"] == train.t.numel() == len(range(0, 160_001, info["factor"]))
    assert train.info["sample_time"] == pytest.approx(info["factor"] / 2000)
    assert held_out.info["decimated"]["factor"] == info["factor"]  # held out at the training rate
    assert "the training record's" in held_out.info["decimated"]["rule"]


@pytest.mark.slow
def test_decimation_keeps_the_diagnosis_of_a_finely_sampled_record():
    """The same system and noise at 2000 and at 200 000 samples: the same verdict and exponent."""
    case = "msd_quadratic_drag"
    frames = finer_records(case, 40.0, 2000, 200_000, 0.01, 0)
    config = {"model": WITHHELD[case].model, "data": {"time": "t", "columns": {"x": "x", "u": "u"}}}
    reports = {n: diagnose(config, data=frame) for n, frame in frames.items()}
    coarse, fine = reports[2000], reports[200_000]
    assert "decimated" not in coarse.data["train"] and fine.data["train"]["decimated"]["factor"] > 50
    assert fine.verdict == coarse.verdict == "gap explained by quadratic drag"
    assert fine.equations[0].exponent == pytest.approx(coarse.equations[0].exponent, abs=0.05)
