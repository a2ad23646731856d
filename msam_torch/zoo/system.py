"""A first-principles system of the zoo, written as the paper's state equations (Eq. 2):
``target = sum_i theta_i M_i`` with ``M_i`` a product of states and inputs, plus the effects one
of them may withhold.

The right-hand side is evaluated here with numpy, independently of the package's own model code
(:mod:`msam_torch.simulation`), so the simulated truth does not share a bug with what it checks.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from msam_torch.model.spec import split_derivative


def factors(term: str) -> list[tuple[str, ...]]:
    """The factors of ``term``, each the signals it reads: ``'prey*pred'`` -> ``[('prey',), ('pred',)]``;
    a difference of two signals of one quantity (``'x1 - x2'``: a spring between two bodies) is one
    factor ``('x1', 'x2')``; ``'1'`` is a constant (no factor)."""
    return [tuple(s.strip() for s in f.split(" - ")) for f in term.split("*") if f != "1"]


def term_value(term: str, values: dict) -> np.ndarray:
    """``M``: the product of the factors of ``term`` (:func:`factors`)."""
    out = 1.0
    for names in factors(term):
        out = out * (values[names[0]] - values[names[1]] if len(names) == 2 else values[names[0]])
    return out


def term_scale(term: str, scale: dict) -> float:
    """The unit factor of ``term`` from its signals' (a difference shares its signals' unit)."""
    return float(np.prod([scale[names[0]] for names in factors(term)]))


def differences(terms) -> list[str]:
    """The differences of two signals among the factors of ``terms``, in order of appearance."""
    found = [" - ".join(names) for term in terms for names in factors(term) if len(names) == 2]
    return list(dict.fromkeys(found))


def power(m: np.ndarray, f: np.ndarray, gamma: float, smooth: float) -> np.ndarray:
    """``M |f|^gamma``; a negative exponent reads ``(f^2 + smooth^2)^(gamma/2)`` so that Coulomb-type
    terms stay integrable through ``f = 0`` (``smooth`` is a small share of the signal's scale)."""
    if gamma >= 0:
        return m * np.abs(f) ** gamma
    return m * (f * f + smooth * smooth) ** (gamma / 2)


@dataclass(frozen=True)
class Equation:
    """``target = sum theta_i term_i``; input components are not adjustable (they are the drive)."""

    target: str
    terms: tuple[str, ...]
    theta: tuple[float, ...]

    @property
    def state(self) -> str:
        return split_derivative(self.target)[0]


@dataclass(frozen=True)
class Effect:
    """An effect the starting model may lack.

    ``form``: 'additive' (``+ c M |f|^gamma``), 'multiplicative' (the component ``theta M``
    replaced by ``c M |f|^gamma``) or one of the input nonlinearities of :mod:`.effects`
    (out of the catalogue). ``name`` is the catalogue name a diagnosis should give."""

    name: str
    target: str = ""
    component: str = ""
    function: str = ""
    form: str = "additive"
    exponent: tuple[float, float] = (0.0, 0.0)  # drawn uniformly in this range
    sign: float = -1.0  # sign of c (dissipative effects oppose the motion)
    catalogued: bool = True
    exchange: str = ""  # a signal whose same power is subtracted (radiation exchange with the ambient)
    also: tuple[tuple[str, float], ...] = ()  # further targets, each with its coefficient relative to
    # ``target``'s: an effect between two bodies or tanks acts on both (the reaction, the flow into the other)

    @property
    def targets(self) -> tuple[str, ...]:
        return (self.target, *(t for t, _ in self.also))

    def weight(self, target: str) -> float:
        """The effect's coefficient in ``target``'s equation relative to ``self.target``'s (0: absent)."""
        return 1.0 if target == self.target else dict(self.also).get(target, 0.0)


@dataclass(frozen=True)
class System:
    """A drawn system in SI units: equations with true theta, signal quantities, excitation needs."""

    domain: str
    name: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    equations: tuple[Equation, ...]
    quantities: dict
    initial: dict  # state -> value at t = 0
    magnitude: dict  # state -> its typical size (sets the solver's absolute tolerance)
    period: float  # a characteristic period of the dynamics (s): sets the sampling rate
    effects: tuple[Effect, ...]
    drive: dict = field(default_factory=dict)  # input -> (offset, amplitude); positive inputs have offset > amplitude
    positive: tuple[str, ...] = ()  # states that must stay > 0
    measured: tuple[tuple[str, ...], ...] = ()  # measurable subsets of the states
    autonomous: bool = False  # no input: excited by random initial states
    initial_spread: dict = field(default_factory=dict)  # autonomous: state -> (low, high) of a random start

    def equation(self, target: str) -> Equation:
        return next(e for e in self.equations if e.target == target)

    def state_rates(self, values: dict, effect=None) -> dict:
        """Right-hand side of every equation at ``values`` (signals by name), ``effect`` included."""
        out = {}
        for eq in self.equations:
            total = 0.0
            for term, theta in zip(eq.terms, eq.theta):
                if effect is not None and effect.replaces(eq.target, term):
                    continue
                total = total + theta * term_value(term, values)
            if effect is not None:
                total = total + effect.contribution(eq.target, values)
            out[eq.target] = total
        return out

    def derivative_map(self) -> dict:
        """state -> the name of its time derivative (``x -> x_dot``); second-order pairs resolve to
        their ``_ddot`` equation through the velocity state."""
        names = {}
        for x in self.states:
            base, order = split_derivative(x)
            names[x] = base + {0: "_dot", 1: "_ddot"}[order]
        return names
