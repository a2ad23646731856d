"""The benchmark data slices follow the official splits, and the naive starting configs of
issue 16 load, stay plain and run through msam diagnose / msam run (experiments/realdata/benchmarks.py)."""
from pathlib import Path

import pytest

from msam_torch.config.schema import AdaptationConfig, SimulationConfig, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data import datasets
from msam_torch.diagnosis import NOT_CATALOGUED, DiagnoseOptions, diagnose
from msam_torch.run.adapt import adapt

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
NAIVE = ["silverbox_naive", "emps_naive", "cascaded_tanks_naive"]


def test_silverbox_slices_are_the_official_split():
    """nonlinear-benchmarks Silverbox(): train = first 75 % of rows 40,650-127,399; test arrow =
    rows 100-40,574, of which the first 32,000 are the no-extrapolation subset."""
    train = datasets.load("silverbox", "train_multisine")
    test = datasets.load("silverbox", "test_arrow")
    assert len(train) == 65_062 == int(0.75 * (127_400 - 40_650))
    assert (train["sample"].iloc[0], train["sample"].iloc[-1]) == (40_650, 105_711)
    assert len(test) == 40_475 and (test["sample"].iloc[0], test["sample"].iloc[-1]) == (100, 40_574)
    assert test["sample"].iloc[31_999] == 32_099
    assert list(train.columns) == ["sample", "t_s", "V1", "V2"]
    tail = datasets.load("silverbox", "arrow_tail")  # the older slice is a part of the test record
    assert test.set_index("sample").loc[tail["sample"], "V2"].tolist() == tail["V2"].tolist()


@pytest.mark.parametrize("name, records, rows", [
    ("emps", ["emps_estimation", "emps_validation_pulses"], 24_841),
    ("cascaded_tanks", ["estimation", "validation"], 1_024),
])
def test_estimation_and_validation_records_are_complete(name, records, rows):
    for record in records:
        assert len(datasets.load(name, record)) == rows


@pytest.mark.parametrize("name", NAIVE)
def test_naive_configs_hold_only_the_starting_physics(name):
    config = load_config(CONFIGS / f"{name}.yaml")
    spec = to_spec(config.model)
    for equation in config.model.equations:
        terms = [c.term for c in equation.components]
        assert len(set(terms)) == len(terms)  # no component split
        assert all(c.adjustments is None and c.start is None and c.adjustable for c in equation.components)
        assert equation.adjustments == [f"abs({s})" for s in spec.states]  # F built from the states
    defaults = AdaptationConfig().model_dump()
    changed = {k for k, v in config.adaptation.model_dump().items() if v != defaults[k]}
    simulated = config.adaptation.evaluation == "simulation"
    assert changed == ({"evaluation", "simulation"} if simulated else set())
    sim = config.adaptation.simulation.model_dump()
    assert {k for k, v in sim.items() if v != SimulationConfig().model_dump()[k]} == ({"output"} if simulated else set())
    assert config.data.derivatives == "auto" and config.data.validation_file is not None


def test_naive_emps_diagnosis_runs_on_a_slice():
    """The first 10 s of the estimation record, held out on the validation pulses: a friction
    copy of the viscous term with a 60 % held-out improvement. Its total exponent -0.12 +- 0.20 (4
    trials) lies in the Stribeck-like range and holds Coulomb's 0 too: the interval does not tell
    them apart, so neither names it and the report says so."""
    report = diagnose(CONFIGS / "emps_naive.yaml", overrides=["data.train.stop=10"],
                      options=DiagnoseOptions(bootstrap=4, free_run=False))
    (gap,) = report.equations
    assert gap.effect == NOT_CATALOGUED and gap.exponent == pytest.approx(-1.118, abs=0.03)
    assert "consistent with Coulomb friction and Stribeck-like power-law friction" in gap.naming["text"], gap.naming
    assert gap.improvement["relative"] == pytest.approx(0.604, abs=0.03)
    assert gap.confidence["margin"] > 0.02


def test_naive_silverbox_run_keeps_the_nominal_theta_under_the_paper_preset():
    """The paper's step keeps theta at the user's guesses (theta: fixed), so msam run on the
    naive config adapts exponents around -10 y_dot - 1e5 y + u."""
    result = adapt(CONFIGS / "silverbox_naive.yaml", ["data.train.by=index", "data.train.stop=4000", "adaptation.preset=paper",
                                                      "adaptation.round_robin_steps=2", "adaptation.refinement_steps=2"])
    (equation,) = result.equations
    assert equation.theta == pytest.approx([-10.0, -1.0e5, 1.0])
    assert len(equation.ranking) == 2 ** 3
