"""Unit invariance (docs/design.md 2.7): with ``normalize: rms`` the same data and model in other
units give the same selection and exponents. The converted data go through a CSV file."""
import pytest
import yaml

from msam_torch.run.adapt import adapt
from tests.helpers import measured_case

# Theta re-solved at every step (variable projection) finds the true forms; van der Pol's two
# copies of x_dot must start apart or they stay identical (design notes section 3).
VARPRO = ["adaptation.normalize=rms", "adaptation.theta=varpro"]
QUICK = ["adaptation.round_robin_steps=10", "adaptation.refinement_steps=10"]
CASES = {
    "harmonic": (["abs(x_dot)", "abs(x)", None], [(1e-3, 1.0), (1e3, 1.0)]),
    "vanderpol": (["abs(x)", "abs(x)", "*"], [(1e-3, 1.0), (1e3, 1.0), (1.0, 1e-3), (1.0, 1e3)]),
}


def run(tmp_path, name, length, time, overrides):
    config, frame = measured_case(name, length, time, every=2)
    if name == "vanderpol":
        config["model"]["equations"][0]["components"][1]["start"] = 0.5
    folder = tmp_path / f"{name}_{length:g}_{time:g}"
    folder.mkdir()
    frame.to_csv(folder / "data.csv", index=False)
    config["data"]["file"] = "data.csv"
    (folder / "config.yaml").write_text(yaml.safe_dump(config))
    return adapt(folder / "config.yaml", QUICK + overrides).equations[0]


@pytest.mark.parametrize("name", CASES)
def test_selection_and_exponents_do_not_depend_on_units(tmp_path, name):
    expected, conversions = CASES[name]
    reference = run(tmp_path, name, 1.0, 1.0, VARPRO)
    assert all(e in ("*", a) for e, a in zip(expected, reference.adjustments)), reference.equation
    for length, time in conversions:
        converted = run(tmp_path, name, length, time, VARPRO)
        assert converted.adjustments == reference.adjustments, (length, time, converted.equation)
        for a, b in zip(converted.exponents, reference.exponents):
            assert (a is None and b is None) or abs(a - b) < 1e-6, (length, time, converted.exponents, reference.exponents)


def test_normalisation_alone_is_invariant_with_theta_fixed(tmp_path):
    """Every column the step sees is dimensionless, so even the literal step is invariant."""
    reference = run(tmp_path, "vanderpol", 1.0, 1.0, ["adaptation.normalize=rms", "adaptation.theta=fixed"])
    converted = run(tmp_path, "vanderpol", 1e3, 1e-3, ["adaptation.normalize=rms", "adaptation.theta=fixed"])
    assert converted.adjustments == reference.adjustments
    assert max(abs(a - b) for a, b in zip(converted.exponents, reference.exponents)) < 1e-6


def test_without_normalisation_units_change_the_result(tmp_path):
    """The reason for the option: |f|^gamma is not unit-invariant (docs/design.md 2.7)."""
    reference = run(tmp_path, "harmonic", 1.0, 1.0, ["adaptation.normalize=none"])
    converted = run(tmp_path, "harmonic", 1e3, 1.0, ["adaptation.normalize=none"])
    assert (converted.adjustments != reference.adjustments
            or max(abs(a - b) for a, b in zip(converted.exponents[:2], reference.exponents[:2])) > 1e-3)
