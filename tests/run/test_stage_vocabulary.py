"""The JSON files of a run and a diagnosis. One stage vocabulary for the four models: ``start``,
``retuned``, ``adapted`` and ``adapted_retuned``: every key of a run's ``result.json`` and of a
diagnosis's ``gap_report.json`` (several effects in turn, held-out data and theta re-estimation
included) is read, and none names a stage another way (``final``, ``tuned``, ``start_tuned``, ...).
``gap_report.json`` validates against the schema published in the docs, which is the one generated
from the report's types."""
import json
import re
from pathlib import Path

import jsonschema
import pytest

from msam_torch import DiagnoseOptions, adapt, diagnose
from msam_torch.diagnosis.report.json_schema import gap_report_schema
from tests.diagnosis.test_diagnose import case_data
from tests.helpers import QUICK, measured_case

STAGES = {"start", "retuned", "adapted", "adapted_retuned"}
OTHER_NAMES = {"final", "tuned", "refitted", "initial_model", "nominal_model"}


def keys(value) -> set[str]:
    """Every key of a JSON document, at any depth."""
    if isinstance(value, dict):
        return set(value) | {k for v in value.values() for k in keys(v)}
    if isinstance(value, list):
        return {k for v in value for k in keys(v)}
    return set()


def other_stage_names(document: dict) -> set[str]:
    return {k for k in keys(document) if set(re.split(r"[^a-z]+", k.lower())) & OTHER_NAMES}


@pytest.fixture(scope="module")
def run_json(tmp_path_factory) -> dict:
    config, frame = measured_case("harmonic", every=2)
    config["data"].update(train={"stop": 2.0}, validation={"start": 2.0 + 1e-9})
    result = adapt(config, QUICK + ["adaptation.tune_theta=true"], data=frame)
    return json.loads(result.save(tmp_path_factory.mktemp("run") / "result.json").read_text())


@pytest.fixture(scope="module")
def report_json(tmp_path_factory) -> dict:
    w, (train, held_out) = case_data("msd_coulomb")
    report = diagnose({"model": w.model}, data=train, validation=held_out,
                      options=DiagnoseOptions(bootstrap=6, steps=20, max_effects=2))
    return json.loads(report.save(tmp_path_factory.mktemp("diagnosis"), plots=False).read_text())


def test_result_json_names_the_stages_one_way(run_json):
    equation = run_json["equations"][0]
    assert set(equation["validation"]) == STAGES
    assert {"retuned", "adapted_retuned"} <= set(equation["theta_tuning"])
    assert {"start", "adapted"} <= set(equation)
    assert other_stage_names(run_json) == set()


def test_gap_report_json_names_the_stages_one_way(report_json):
    free_run = report_json["measures"]["free_run"]["held_out"]["nrmse"]
    assert set(free_run) == {"start", "retuned", "adapted"}
    assert "accepted_model" in report_json["in_turn"]
    assert other_stage_names(report_json) == set()


def test_the_check_finds_another_name():
    assert other_stage_names({"a": [{"final": 1}], "theta_tuning": {"start_tuned": 2}}) == {"final", "start_tuned"}


PUBLISHED = Path(__file__).resolve().parents[2] / "docs" / "gap_report.schema.json"


def test_the_published_schema_is_the_generated_one():
    """``python -m msam_torch.diagnosis.report.json_schema > docs/gap_report.schema.json`` after a change of the types."""
    assert json.loads(PUBLISHED.read_text()) == gap_report_schema()


def test_gap_report_json_validates_against_the_published_schema(report_json):
    schema = json.loads(PUBLISHED.read_text())
    jsonschema.validate(report_json, schema)
    broken = json.loads(json.dumps(report_json))
    broken["equations"][0]["confidence"]["win_frequency"] = "high"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(broken, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({k: v for k, v in report_json.items() if k != "verdict_kind"}, schema)
