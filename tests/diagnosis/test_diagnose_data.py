"""``adapt`` and ``diagnose`` take the same data arguments: a CSV/Parquet path, a pandas DataFrame,
a mapping of column to array or tensor, or a Dataset; anything else is an MSAMError naming the
argument. The verdict renders to the report's text."""
import json

import pandas as pd
import pytest
import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import resolve_datasets
from msam_torch.data.systems import WITHHELD
from msam_torch.diagnosis import Verdict, diagnose
from msam_torch.errors import DataError, MSAMError
from msam_torch.run.adapt import adapt
from tests.diagnosis.test_diagnose import true_signals
from tests.helpers import ONE_STEP, QUICK

CASE = WITHHELD["msd_quadratic_drag"]
CONFIG = {"model": CASE.model, "data": {"time": "time", "columns": {"x": "pos", "u": "force"}, "derivatives": "savgol"}}


def frames():
    """Training and held-out records of the quadratic-drag case as DataFrames in the config's columns."""
    return [pd.DataFrame({"time": s["t"], "pos": s["x"], "force": s["u"]})
            for s in (true_signals(CASE.system), true_signals(CASE.held_out))]


def test_diagnose_takes_frames_mappings_files_and_datasets_alike(tmp_path):
    train, held = frames()
    train.to_csv(tmp_path / "train.csv", index=False)
    held.to_parquet(tmp_path / "held.parquet")
    as_mapping = lambda f: {c: torch.tensor(f[c].to_numpy()) for c in f}
    spec = to_spec(load_config(CONFIG).model)
    datasets = resolve_datasets(load_config(CONFIG).data, spec, data=train, validation=held)
    reports = [diagnose(CONFIG, data=a, validation=b, options=ONE_STEP) for a, b in (
        (train, held), (as_mapping(train), as_mapping(held)), (tmp_path / "train.csv", str(tmp_path / "held.parquet")),
        datasets)]
    for report in reports:
        gap = report.equations[0]
        assert report.verdict_kind is Verdict.EXPLAINED and report.verdict == "gap explained by quadratic drag"
        assert gap.exponent == pytest.approx(reports[0].equations[0].exponent, abs=1e-9)
        assert gap.exponent == pytest.approx(1.0, abs=0.1)
        assert gap.improvement["relative"] == pytest.approx(reports[0].equations[0].improvement["relative"], abs=1e-9)
    assert reports[0].data["train"]["source"].startswith("data frame")
    assert "train.csv" in reports[2].data["train"]["source"] and "held.parquet" in reports[2].data["held_out"]["source"]


def test_adapt_takes_a_frame_a_file_and_a_dataset_like_diagnose(tmp_path):
    train, held = frames()
    train.to_csv(tmp_path / "train.csv", index=False)
    spec = to_spec(load_config(CONFIG).model)
    dataset, _ = resolve_datasets(load_config(CONFIG).data, spec, data=train)
    results = [adapt(CONFIG, QUICK, data=d, validation=held) for d in (train, tmp_path / "train.csv")]
    results.append(adapt(CONFIG, QUICK, data=dataset))
    exponents = [r.equations[0].exponents for r in results]
    assert exponents[0] == exponents[1] == exponents[2]
    assert results[0].data["validation"]["samples"] == len(held) and "validation" not in results[2].data


def test_a_wrong_data_argument_is_an_error_naming_it():
    train, held = frames()
    with pytest.raises(DataError, match="^data: expected a CSV/Parquet path, a pandas DataFrame"):
        diagnose(CONFIG, data=train.to_numpy(), options=ONE_STEP)
    with pytest.raises(DataError, match="^validation: expected .* got list"):
        adapt(CONFIG, QUICK, data=train, validation=[1.0, 2.0])
    spec = to_spec(load_config(CONFIG).model)
    dataset, _ = resolve_datasets(load_config(CONFIG).data, spec, data=train)
    with pytest.raises(MSAMError, match="^validation: with data given as a Dataset"):
        diagnose(CONFIG, data=dataset, validation=held, options=ONE_STEP)
    with pytest.raises(DataError, match="^validation: held-out data from a file or table need measured training data"):
        adapt({"model": CASE.model, "data": {"system": CASE.system}}, QUICK, validation=held)


def test_verdicts_render_the_report_text():
    assert Verdict.EXPLAINED.text("Coulomb friction") == "gap explained by Coulomb friction"
    assert Verdict.NO_GAP.text() == "no significant gap"
    assert Verdict.NOT_EXPLAINED.text() == "gap not explained by a catalogued effect"
    assert json.dumps({k.name: k for k in Verdict}) == ('{"EXPLAINED": "explained", "NO_GAP": "no_gap", '
                                                         '"NOT_EXPLAINED": "not_explained", "INCONCLUSIVE": "inconclusive"}')
