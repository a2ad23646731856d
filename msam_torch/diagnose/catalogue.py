"""The effect catalogue: map a selected adjustment to a named physical effect (design.md section 3).

An effect term is ``theta * M * |s|^gamma`` (``abs(s)`` adjustment) added to a state equation
(additive: a copy of component ``M``) or replacing ``M`` (multiplicative). Signal roles come from
the spec's naming alone: in an equation for the ``k``-th derivative of ``x``, ``x`` differentiated
``k - 1`` times is the *rate* (velocity in a force balance, the level in a balance of flows when
``k = 1``) and ``k - 2`` times the *displacement*. An entry matches when roles agree and the
exponent is within its interval; anything else is "power law, no catalogued effect". A fitted
exponent just outside an interval (noise biases exponents, design.md section 3) still takes the
name when the exponent *snapped* to the interval keeps most of the improvement (see
:mod:`msam_torch.diagnose.naming`).

| effect | term | exponent gamma |
|---|---|---|
| Coulomb friction | rate * abs(rate)^gamma (k >= 2) | -1 +- 0.2 (sign of the rate) |
| power-law damping | rate * abs(rate)^gamma (k >= 2) | 0.25 .. 0.75 |
| quadratic drag | rate * abs(rate)^gamma (k >= 2) | 1 +- 0.2 |
| hardening / softening cubic stiffness | displacement * abs(displacement)^gamma | 2 +- 0.2; hardening when theta has the sign of the starting stiffness |
| van der Pol-type damping | rate * abs(displacement)^gamma | 2 +- 0.2 |
| Torricelli outflow | level * abs(level)^gamma (k = 1) | -0.5 +- 0.2 (square root of the level) |
"""
from __future__ import annotations

from dataclasses import dataclass

from ..spec import Equation, split_derivative

NOT_CATALOGUED = "power law, no catalogued effect"
TOLERANCE = 0.2


@dataclass(frozen=True)
class Entry:
    name: str
    term: str  # role of M: 'rate', 'displacement', 'level'
    function: str  # role of the adjusted signal
    low: float
    high: float
    orders: tuple[int, ...]  # target derivative orders the entry applies to

    def matches(self, term_role: str, function_role: str, gamma: float, order: int) -> bool:
        return (term_role == self.term and function_role == self.function and order in self.orders
                and self.low <= gamma <= self.high)


CATALOGUE: tuple[Entry, ...] = (
    Entry("Coulomb friction", "rate", "rate", -1 - TOLERANCE, -1 + TOLERANCE, (2,)),
    Entry("power-law damping", "rate", "rate", 0.25, 0.75, (2,)),
    Entry("quadratic drag", "rate", "rate", 1 - TOLERANCE, 1 + TOLERANCE, (2,)),
    Entry("cubic stiffness", "displacement", "displacement", 2 - TOLERANCE, 2 + TOLERANCE, (2,)),
    Entry("van der Pol-type damping", "rate", "displacement", 2 - TOLERANCE, 2 + TOLERANCE, (2,)),
    Entry("Torricelli outflow", "level", "level", -0.5 - TOLERANCE, -0.5 + TOLERANCE, (1,)),
)


def role(equation: Equation, text: str) -> str | None:
    """'rate', 'displacement' or 'level' of a plain signal name in ``equation``, else None."""
    if not text.isidentifier():
        return None
    base, order = split_derivative(equation.target)
    signal_base, signal_order = split_derivative(text)
    if signal_base != base:
        return None
    if order == 1 and signal_order == 0:
        return "level"
    if order >= 2 and signal_order == order - 1:
        return "rate"
    if order >= 2 and signal_order == order - 2:
        return "displacement"
    return None


def entries_for(equation: Equation, component: int, function: int) -> list[Entry]:
    """Catalogue entries whose roles fit ``M_component * f_function^gamma`` (any exponent)."""
    f = equation.adjustments[function]
    if not f.is_magnitude:
        return []
    term_role = role(equation, equation.components[component].term.text)
    function_role = role(equation, f.inner_text)
    order = split_derivative(equation.target)[1]
    return [e for e in CATALOGUE if e.term == term_role and e.function == function_role and order in e.orders]


def name_effect(equation: Equation, component: int, function: int, gamma: float, theta: float,
                starting_theta: float) -> str:
    """The catalogue name of ``theta * M_component * f_function^gamma``, or :data:`NOT_CATALOGUED`."""
    f = equation.adjustments[function]
    if not f.is_magnitude:
        return NOT_CATALOGUED
    term_role = role(equation, equation.components[component].term.text)
    function_role = role(equation, f.inner_text)
    order = split_derivative(equation.target)[1]
    for entry in CATALOGUE:
        if entry.matches(term_role, function_role, gamma, order):
            if entry.name == "cubic stiffness":
                kind = "hardening" if theta * starting_theta > 0 else "softening"
                return f"{kind} cubic stiffness"
            return entry.name
    return NOT_CATALOGUED
