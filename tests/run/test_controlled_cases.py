"""Acceptance on the controlled cases of Table 1 (exact derivative targets, 0 % parametric error)."""

from msam_torch.run.adapt import adapt
from tests.helpers import CONFIGS


def test_harmonic_selects_both_adjustments_with_exact_exponents():
    eq = adapt(CONFIGS / "harmonic.yaml").equations[0]
    assert eq.adjustments == ["abs(x_dot)", "abs(x)", None]
    assert abs(eq.exponents[0] - 1.0) < 0.01 and abs(eq.exponents[1] - 2.0) < 0.01
    assert eq.adapted["sum_abs_error"] < 1e-6 * eq.start["sum_abs_error"]
    assert eq.equation == "x_ddot = -26.13 x_dot|x_dot|^1.000 - 346.7 x|x|^2.000 + 0.002667 u"


def test_vanderpol_first_component_gets_x_squared_and_the_others_stay_small():
    eq = adapt(CONFIGS / "vanderpol.yaml").equations[0]
    assert eq.adjustments[0] == "abs(x)"
    assert abs(eq.exponents[0] - 2.0) < 0.05
    assert all(abs(g) < 0.15 for g in eq.exponents[1:])


def test_third_order_model_gets_the_correct_adjustment_set_in_every_equation():
    result = adapt(CONFIGS / "sode3.yaml")
    expected = {"x1_dot": ["x3", "x3", "x3"], "x2_dot": ["x2", "x1", "x3"], "x3_dot": ["x2", "x1", "x3"]}
    for eq in result.equations:
        assert eq.adjustments == expected[eq.target], eq.target
        assert all(abs(g - 1.0) < 0.05 for g in eq.exponents), (eq.target, eq.exponents)
