"""The paper's notation of an adjusted equation (Eq. 9) as text: one component
(``x_dot|x_dot|^1.000``) and a whole equation (``x_ddot = -26.13 x_dot|x_dot|^1.000 - ...``)."""
from __future__ import annotations

from msam_torch.model.spec import Equation


def _number(value: float) -> str:
    return f"{value:.4g}"


def format_component(equation: Equation, index: int, function: int | None, gamma: float | None) -> str:
    """``x_dot|x_dot|^1.000`` (magnitude) or ``x1 sgn(x3)|x3|^1.000`` (signed); unadjusted: ``u``."""
    term = equation.components[index].term.text
    if any(op in term for op in "+-"):  # a sum reads as one factor: (c + i + g)|y|^0.5
        term = f"({term})"
    if function is None:
        return term
    f = equation.adjustments[function]
    inner = f.inner_text
    inner = inner if inner.isidentifier() else f"({inner})"
    power = f"{gamma:.3f}".replace("-0.000", "0.000")  # an exponent that rounds to zero has no sign
    adjustment = f"|{inner}|^{power}" if f.is_magnitude else f"sgn({inner})|{inner}|^{power}"
    return f"{term}{adjustment}" if term.isidentifier() and f.is_magnitude else f"{term} {adjustment}"


def format_equation(target: str, thetas: list[float], terms: list[str]) -> str:
    """``x_ddot = -26.13 x_dot|x_dot|^1.000 - 346.7 x|x|^2.000 + 0.002667 u - 0.5`` (a constant term
    ``1`` is its value alone)."""
    parts = []
    for theta, term in zip(thetas, terms):
        sign = "-" if theta < 0 else "+"
        body = _number(abs(theta)) if term == "1" else f"{_number(abs(theta))} {term}"  # a constant: its value
        parts.append(f"{sign} {body}" if parts else (f"-{body}" if theta < 0 else body))
    return f"{target} = " + " ".join(parts)
