"""Withheld effects as drawn: a catalogued power-law term with its coefficient and exponent, or an
out-of-catalogue input nonlinearity (dead zone, saturation, backlash, hysteresis) applied to the
drive before it reaches the system.

Backlash is the play operator; hysteresis a Prandtl-Ishlinskii sum of play operators. Both depend
on the input's history only, so they are applied to the densely sampled input before the
simulation (:mod:`.case`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msam_torch.zoo.system import Effect, power, term_value

OUT_OF_CATALOGUE = ("dead zone", "saturation", "backlash", "hysteresis")
# The name (a part of it, lower case) a catalogue entry for an input threshold law would carry: a
# diagnosis may name it once the catalogue holds such an entry; until then the right answer is
# "gap not explained by a catalogued effect" or "inconclusive" (:func:`~msam_torch.zoo.score.score`)
EXPECTED_NAMES = {"saturation": "saturation", "dead zone": "dead zone"}


@dataclass(frozen=True)
class DrawnEffect:
    """An :class:`Effect` with its coefficient ``c`` (SI units), exponent and smoothing scale."""

    effect: Effect
    coefficient: float = 0.0
    gamma: float = 0.0
    smooth: float = 0.0
    width: float = 0.0  # input nonlinearities: dead-zone half-width, saturation level or play width
    input: str = ""
    centre: float = 0.0  # input nonlinearities act on the deviation from the drive's operating point

    def replaces(self, target: str, term: str) -> bool:
        e = self.effect
        return e.form == "multiplicative" and e.weight(target) != 0 and e.component == term

    def contribution(self, target: str, values: dict):
        e = self.effect
        if e.form not in ("additive", "multiplicative") or e.weight(target) == 0:
            return 0.0
        value = power(term_value(e.component, values), term_value(e.function, values), self.gamma, self.smooth)
        if e.exchange:  # radiation exchange: c (T|T|^g - Ta|Ta|^g)
            value = value - power(values[e.exchange], values[e.exchange], self.gamma, self.smooth)
        return e.weight(target) * self.coefficient * value

    def shape_input(self, u: np.ndarray) -> np.ndarray:
        """The input the system feels (input nonlinearities only; else ``u`` itself)."""
        form, w, d = self.effect.form, self.width, u - self.centre
        if form == "dead zone":
            return self.centre + np.sign(d) * np.maximum(np.abs(d) - w, 0.0)
        if form == "saturation":
            return self.centre + np.clip(d, -w, w)
        if form == "backlash":
            return play(u, w)
        if form == "hysteresis":
            return np.mean([play(u, r) for r in w * np.linspace(0.2, 1.0, 5)], axis=0)
        return u

    def describe(self) -> dict:
        e = self.effect
        out = {"name": e.name, "catalogued": e.catalogued, "form": e.form}
        if e.form in ("additive", "multiplicative"):
            out.update(target=e.target, component=e.component, function=e.function, exponent=self.gamma,
                       coefficient_si=self.coefficient)
        else:
            out.update(input=self.input, width_si=self.width, expected_name=EXPECTED_NAMES.get(e.form))
        return out


@dataclass(frozen=True)
class Combined:
    """Several catalogued power-law effects withheld at once (each a :class:`DrawnEffect` with its own
    coefficient); the system feels their sum. No input nonlinearity: the input is felt as it is."""

    parts: tuple[DrawnEffect, ...]
    input: str = ""

    def replaces(self, target: str, term: str) -> bool:
        return any(p.replaces(target, term) for p in self.parts)

    def contribution(self, target: str, values: dict):
        return sum(p.contribution(target, values) for p in self.parts)

    def shape_input(self, u: np.ndarray) -> np.ndarray:
        return u


def separable(a: Effect, b: Effect) -> bool:
    """Two catalogued power laws a diagnosis can tell apart when both are withheld: not both replacing
    the same component, and on the same component and function at least one apart in exponent (closer
    laws on one signal sum to one law between them)."""
    same = (a.target, a.component, a.function) == (b.target, b.component, b.function)
    if same and "multiplicative" in (a.form, b.form):
        return False
    apart = max(b.exponent[0] - a.exponent[1], a.exponent[0] - b.exponent[1])
    return not same or apart >= 1.0


def play(u: np.ndarray, width: float) -> np.ndarray:
    """The play (backlash) operator of half-width ``width``, started centred on ``u[0]``."""
    out = np.empty_like(u)
    y = u[0]
    for k, v in enumerate(u):
        y = min(max(y, v - width), v + width)
        out[k] = y
    return out


def input_effects(inputs: tuple[str, ...], targets: tuple[str, ...]) -> tuple[Effect, ...]:
    """The out-of-catalogue effects available to a system driven through ``inputs[0]``."""
    if not inputs:
        return ()
    return tuple(Effect(name, target=",".join(targets), component=inputs[0], form=name, catalogued=False)
                 for name in OUT_OF_CATALOGUE)
