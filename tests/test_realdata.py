"""The carried benchmark records: the loader, and one case end to end on a small slice."""
from pathlib import Path

import pytest

from msam_torch import datasets
from msam_torch.api import adapt
from msam_torch.config import load_config
from msam_torch.data import load_datasets
from msam_torch.spec import ModelSpec
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
    """EMPS, the first 6 s of the estimation record: the split viscous term becomes viscous plus a
    Coulomb-like law (q_dot |q_dot|^gamma, gamma near -1) whose force at the median speed is near the
    published Fc = 20.4 N, and the mass near 95 kg."""
    config = load_config(CONFIGS / "emps.yaml", ["data.train.stop=6.0", "data.validation_file=null",
                                                 "adaptation.refinement_steps=10"])
    result = adapt(config, base_dir=CONFIGS)
    eq = result.equations[0]
    coulomb = [i for i, (a, g) in enumerate(zip(eq.adjustments, eq.exponents))
               if a == "abs(q_dot)" and g is not None and g < -0.7]
    assert len(coulomb) == 1, eq.equation
    k = coulomb[0]
    mass = 1.0 / eq.theta[0]
    train, _ = load_datasets(config.data, ModelSpec.from_config(config.model), CONFIGS)
    speed = float(train.signals["q_dot"].abs().median())
    friction = -eq.theta[k] * mass * speed ** (1.0 + eq.exponents[k])
    assert 80 < mass < 115, mass
    assert 14 < friction < 30, friction
