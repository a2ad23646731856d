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

from msam_torch.config.schema import EffectConfig, ModelConfig
from msam_torch.errors import ConfigError
from msam_torch.model.expressions import Expression, parse

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
    effects: tuple[EffectConfig, ...] = field(default=(), kw_only=True)  # the config's own catalogue entries

    @classmethod
    def from_config(cls, config: ModelConfig) -> "ModelSpec":
        names = list(config.states) + list(config.inputs)
        seen = set()
        for i, name in enumerate(names):
            key = f"model.states[{i}]" if i < len(config.states) else f"model.inputs[{i - len(config.states)}]"
            if not name.isidentifier() or name == "t":
                raise ConfigError(key, f"{name!r} is not a valid signal name")
            if name in seen:
                raise ConfigError(key, f"{name!r} is listed twice")
            seen.add(name)
        signals = {"t"} | {derivative_name(split_derivative(n)[0], k) for n in names for k in range(3)}
        signals |= set(names)
        parameters = set(config.parameters)
        if parameters & signals:
            raise ConfigError("model.parameters", f"names shared with signals: {sorted(parameters & signals)}")
        equations = []
        targets = set()
        for e, eq in enumerate(config.equations):
            key = f"model.equations[{e}]"
            base, order = split_derivative(eq.target)
            if eq.target not in signals or order == 0 or derivative_name(base, order - 1) not in config.states:
                raise ConfigError(f"{key}.target", f"{eq.target!r} is not the derivative of a state "
                                  f"(states: {', '.join(config.states) or 'none'})")
            if eq.target in targets:
                raise ConfigError(f"{key}.target", f"{eq.target!r} has two equations")
            targets.add(eq.target)
            adjustments = tuple(
                parse(f, f"{key}.adjustments[{i}]", signals - {eq.target}) for i, f in enumerate(eq.adjustments)
            )
            if len({f.text for f in adjustments}) != len(adjustments):
                raise ConfigError(f"{key}.adjustments", "an adjustment function is listed twice")
            texts = [f.text for f in adjustments]

            def allowed(c, i):  # the component's subset of the equation's adjustment functions
                if c.adjustments is None:
                    return None
                indices = []
                for j, f in enumerate(c.adjustments):
                    where = f"{key}.components[{i}].adjustments[{j}]"
                    text = parse(f, where, signals - {eq.target}).text
                    if text not in texts:
                        raise ConfigError(where, f"{f!r} is not one of the equation's adjustments {texts}")
                    indices.append(texts.index(text))
                if len(set(indices)) != len(indices):
                    raise ConfigError(f"{key}.components[{i}].adjustments", "an adjustment function is listed twice")
                return tuple(indices)

            components = tuple(
                Component(
                    term=parse(c.term, f"{key}.components[{i}].term", signals - {eq.target}),
                    theta=parse(c.theta, f"{key}.components[{i}].theta", parameters),
                    adjustable=c.adjustable,
                    start=float(c.start or 0.0),
                    allowed=allowed(c, i),
                )
                for i, c in enumerate(eq.components)
            )
            if not any(c.adjustable for c in components):
                raise ConfigError(f"{key}.components", "no component is adjustable: mark at least one adjustable "
                                  "(an identity such as d_dot = v1 - v2 is then checked like any equation and "
                                  "reads 'no significant gap' where it holds)")
            equations.append(Equation(eq.target, components, adjustments))
        for name in config.quantities:
            if name not in signals - {"t"}:
                raise ConfigError(f"model.quantities.{name}", f"{name!r} is not a state, an input or a derivative of one")
        quantities = {name: q.quantity for name, q in config.quantities.items()}
        units = {name: q.unit for name, q in config.quantities.items() if q.unit}
        return cls(tuple(config.states), tuple(config.inputs), dict(config.parameters), tuple(equations),
                   quantities=quantities, units=units, effects=tuple(config.effects))

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
