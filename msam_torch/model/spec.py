"""The starting model: states, inputs, parameters and state equations of components (Eq. 2).

Each state equation models a target derivative as ``sum_i theta_i * M_i``. ``M_i`` (a *term*) and
the adjustment functions ``f`` are expressions of *signals*: states, inputs, the time ``t`` and
their derivatives, named by suffix (``x_dot`` is dx/dt, ``x_ddot`` is d2x/dt2). ``theta_i`` is an
expression of the named parameters (``-c/m``) or a number.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import torch

from msam_torch.model.expressions import Expression

SUFFIXES = {"": 0, "_dot": 1, "_ddot": 2}


def split_derivative(name: str) -> tuple[str, int]:
    """``'x_ddot' -> ('x', 2)``, ``'x_dot' -> ('x', 1)``, ``'x' -> ('x', 0)``."""
    for suffix in ("_ddot", "_dot"):
        if name.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)], SUFFIXES[suffix]
    return name, 0


def derivative_name(base: str, order: int) -> str:
    return base + {0: "", 1: "_dot", 2: "_ddot"}[order]


@dataclass(frozen=True)
class Component:
    """``theta * M``; adjustable components are multiplied by ``f^gamma`` (Eq. 8)."""

    term: Expression
    theta: Expression
    adjustable: bool = True
    start: float = 0.0
    allowed: tuple[int, ...] | None = None  # indices into the equation's adjustments (None: all of them)


@dataclass(frozen=True)
class Equation:
    """One state equation: target derivative, components, adjustment set F."""

    target: str
    components: tuple[Component, ...]
    adjustments: tuple[Expression, ...]

    @property
    def adjustable(self) -> tuple[int, ...]:
        return tuple(i for i, c in enumerate(self.components) if c.adjustable)

    def allowed(self, i: int) -> tuple[int, ...]:
        """The adjustment functions (indices into ``adjustments``) component ``i`` may take."""
        allowed = self.components[i].allowed
        return tuple(range(len(self.adjustments))) if allowed is None else allowed

    @property
    def fixed(self) -> tuple[int, ...]:
        return tuple(i for i, c in enumerate(self.components) if not c.adjustable)

    @property
    def signals(self) -> frozenset[str]:
        """Every signal the equation reads, the target included."""
        names = {self.target}
        for c in self.components:
            names |= c.term.names
        for f in self.adjustments:
            names |= f.names
        return frozenset(names)


@dataclass(frozen=True)
class ModelSpec:
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    parameters: Mapping[str, float]
    equations: tuple[Equation, ...]
    quantities: Mapping[str, str] = field(default_factory=dict, kw_only=True)  # signal -> declared quantity
    units: Mapping[str, str] = field(default_factory=dict, kw_only=True)  # signal -> declared unit
    effects: tuple = field(default=(), kw_only=True)  # the config's own catalogue entries (EffectConfig)

    def theta(self, equation: Equation, parameters: Mapping[str, float] | None = None) -> torch.Tensor:
        """Nominal theta of every component of ``equation`` (float64, shape (Q,))."""
        values = dict(self.parameters if parameters is None else parameters)
        return torch.tensor([float(c.theta(values)) for c in equation.components], dtype=torch.float64)

    @property
    def signals(self) -> frozenset[str]:
        names = set()
        for eq in self.equations:
            names |= eq.signals
        return frozenset(names)
