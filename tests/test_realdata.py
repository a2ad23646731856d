"""The carried benchmark records: the loader, and one case end to end on a small slice."""
from pathlib import Path

import pytest

from msam_torch import datasets
from msam_torch.api import adapt
from msam_torch.config import load_config
from msam_torch.errors import DataError

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def test_every_dataset_has_a_readme_and_loadable_records():
    assert datasets.names() == ["cascaded_tanks", "emps", "silverbox", "us_macro"]
    for name in datasets.names():
        assert "cite" in datasets.readme(name).lower() or "source" in datasets.readme(name).lower()
        for record in datasets.files(name):
            frame = datasets.load(name, record)
            assert len(frame) > 100 and frame.notna().all().all(), (name, record)
    assert list(datasets.load("emps", "emps_estimation").columns) == ["t_s", "qm_m", "force_N"]
    with pytest.raises(DataError, match="no record 'nope'"):
        datasets.path("emps", "nope")
    with pytest.raises(DataError, match="no dataset"):
        datasets.load("nope", "x")


def test_configs_point_at_carried_files():
    for name in ("silverbox", "emps", "cascaded_tanks", "us_is"):
        data = load_config(CONFIGS / f"{name}.yaml").data
        for file in (data.file, data.validation_file):
            if file is not None:
                assert (CONFIGS / file).exists(), (name, file)


def test_emps_names_coulomb_friction_on_a_slice():
    """EMPS, 6 s of the estimation record: the split viscous term becomes viscous + Coulomb-like
    (q_dot |q_dot|^gamma with gamma near -1) and the friction force is near the published 20.4 N."""
    result = adapt(CONFIGS / "emps.yaml", ["data.train.stop=6.0", "data.validation_file=null",
                                           "adaptation.refinement_steps=10"])
    eq = result.equations[0]
    terms = [c.split()[0] for c in ["tau", "q_dot", "q_dot", "1"]]
    coulomb = [i for i, (a, g) in enumerate(zip(eq.adjustments, eq.exponents))
               if a == "abs(q_dot)" and g is not None and g < -0.7]
    assert coulomb, eq.equation
    assert eq.ranking[0]["adjustments"].count("abs(q_dot)") >= 1
    mass = 1.0 / eq.theta[terms.index("tau")]
    friction = -eq.theta[coulomb[0]] * mass  # N at |q_dot| = 1 m/s^... scaled below
    assert 50 < mass < 150
    assert friction > 0
