"""Threshold hypotheses (docs/diagnose.md, "Threshold hypotheses"): a saturating actuator, a dead
zone, a saturating spring and an overflowing tank are named with their threshold within 5 % of
the signal's range; power-law effects get no threshold name. Cases: threshold_cases.py (the tests
use seeds 1-2; experiments/suites/thresholds.py reports seeds 100-109)."""
import numpy as np
import pytest
import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.diagnosis import diagnose
from msam_torch.diagnosis.catalogue.entries import Reading, admitted, bundled, threshold_entries
from msam_torch.diagnosis.effects.hypotheses import encode, enumerate_hypotheses, extended_equation
from msam_torch.diagnosis.effects.thresholds import Threshold, switchable
from tests.diagnosis.threshold_cases import OSCILLATOR, clip, dead_zone, oscillator, tank

EQUATION = to_spec(load_config({"model": OSCILLATOR, "data": {"time": "t"}}).model).equations[0]  # x_dot, x, u fixed


@pytest.mark.parametrize("shape, side, law", [
    ("clip", "both", lambda s, c: clip(s, c)), ("dead zone", "both", dead_zone),
    ("hinge", "upper", lambda s, c: np.maximum(s - c, 0.0)), ("hinge", "lower", lambda s, c: np.maximum(c - s, 0.0))])
def test_each_shape_evaluates_as_its_law(shape, side, law):
    u = np.linspace(-3.0, 3.0, 61)
    component = 2 if shape != "hinge" else None
    for c in (0.7, -0.4 if shape == "hinge" else 1.9):
        term = Threshold(shape, "u", side, component, c).expression(EQUATION, {"u"})
        np.testing.assert_allclose(term({"u": torch.tensor(u)}).numpy(), law(u, c), atol=1e-12)


def test_a_clip_switches_its_fixed_component_off_and_its_form_on():
    found = [Threshold("clip", "u", "both", 2, 5.0), Threshold("hinge", "u", "upper", None, 3.0)]
    equation = switchable(EQUATION, found)
    assert equation.adjustable == (0, 1, 2) and equation.allowed(2) == ()  # no power law on the fixed u
    assert [f.text for f in equation.adjustments] == ["abs(x_dot)", "abs(x)", "abs(relu(u - 3))"]
    hypotheses = enumerate_hypotheses(equation, terms=found)
    assert {h.function for h in hypotheses if h.kind == "multiplicative"} == {0, 1}  # nor a hinge's function
    extended = extended_equation(equation, None, found)
    assert [c.term.text for c in extended.components[6:8]] == ["u - relu(u - 5) + relu(-u - 5)", "relu(u - 3)"]
    choices, _ = encode(equation, hypotheses)
    one, zero = 3, 4
    clip_row, hinge_row = choices[-2].tolist(), choices[-1].tolist()
    assert clip_row[:3] == [one, one, zero] and clip_row[6:9] == [one, zero, zero]
    assert hinge_row[:3] == [one, one, one] and hinge_row[6:9] == [zero, 2, zero]


def test_threshold_entries_read_their_quantities():
    undeclared = Reading("velocity", None, None, "u", 1.0)
    assert [e.name for e in threshold_entries(bundled(), "clip", undeclared)] == ["saturation"]
    assert threshold_entries(bundled(), "hinge", undeclared) == []
    level = Reading("level", "level", "level", "h", 1.0)
    assert [e.name for e in threshold_entries(bundled(), "hinge", level)] == ["overflow"]
    position = Reading("velocity", "position", "position", "x", 1.0)
    assert [e.name for e in threshold_entries(bundled(), "hinge", position)] == ["end stop"]
    assert all(e.form in ("additive", "multiplicative") for e in admitted(bundled(), position))  # no threshold

def _diagnosed(effect, seed):
    config, train, held, name, c = tank(seed) if effect == "overflow" else oscillator(seed, effect)
    return diagnose(config, data=train, validation=held).equations[0], train, name, c


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("effect", ["saturation", "dead zone", "spring saturation", "overflow"])
def test_a_threshold_effect_is_named_at_its_threshold(effect, seed):
    gap, train, name, c = _diagnosed(effect, seed)
    assert gap.effect == name and gap.verdict_kind.name == "EXPLAINED", gap.naming
    found = gap.naming["threshold"]
    signal = train[found["signal"]]
    assert abs(found["value"] - c) <= 0.05 * float(signal.max() - signal.min())
    assert found["half_width"] <= 0.1 * found["range"]


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["Coulomb friction", "quadratic drag", "hardening cubic stiffness"])
def test_a_power_law_gets_no_threshold_name(effect):
    gap, _, name, _ = _diagnosed(effect, 1)
    assert gap.effect == name and "threshold" not in gap.naming
