"""The one ODE model of Eq. 9: state equations ``sum_i theta_i M_i f_i^gamma_i + sum_j theta_j M_j``
as the right-hand side of the simulated states, for every use (simulation-based evaluation, free
runs, the diagnosis).

A simulated state's derivative is either an equation's target or another simulated state
(``x_dot`` for ``x``); *external* signals (inputs, and states read from the data in ``separate``
coupling) are interpolated from the record. Adjustment functions are shared between the equations
of a group (``functions``, G distinct expressions); a component's choice ``G`` (:attr:`SystemModel.unadjusted`)
leaves it as in the starting model.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import torch
import torch.autograd.forward_ad as forward_ad

from msam_torch.engine.candidates import FLOOR, power
from msam_torch.errors import ConfigError
from msam_torch.model.spec import Equation, ModelSpec, derivative_name, split_derivative


@dataclass(frozen=True)
class Parameters:
    """Per simulated trajectory (B rows): exponents, choices, theta, fixed theta, function scale."""

    gamma: torch.Tensor  # (B, Qa)
    choice: torch.Tensor  # (B, Qa) long, G for an unadjusted component
    theta: torch.Tensor  # (B, Qa)
    theta_fixed: torch.Tensor  # (B, P)
    scale: torch.Tensor  # (B, G) adjustment functions are divided by it (``normalize: rms``)


@dataclass(frozen=True)
class SystemModel:
    """State equations (Eq. 9) as an ODE right-hand side over the simulated ``states``."""

    states: tuple[str, ...]
    equations: tuple[Equation, ...]
    external: tuple[str, ...]
    source: tuple[int, ...]  # per state: index into cat(states, equation rates)
    adjustable: tuple[tuple[int, int], ...]  # (equation, component) of every adjustable component
    fixed: tuple[tuple[int, int], ...]
    functions: tuple  # distinct adjustment Expressions (G)
    allowed: tuple[tuple[int, ...], ...]  # per adjustable component: indices into functions

    @classmethod
    def build(cls, spec: ModelSpec, equations: tuple[Equation, ...], external: tuple[str, ...]) -> "SystemModel":
        targets = {eq.target: e for e, eq in enumerate(equations)}
        bases = {split_derivative(eq.target)[0] for eq in equations}
        states = tuple(s for s in spec.states if split_derivative(s)[0] in bases)
        source = []
        for s in states:
            base, order = split_derivative(s)
            rate = derivative_name(base, order + 1)
            if rate in targets:
                source.append(len(states) + targets[rate])
            elif rate in states:
                source.append(states.index(rate))
            else:
                raise ConfigError("model.states", f"state {s!r} can be simulated only if {rate!r} is a state or "
                                  "the target of an equation")
        readable = set(states) | set(external) | {"t"}
        for eq in equations:
            unknown = sorted(eq.signals - {eq.target} - readable)
            if unknown:
                where = spec.equations.index(eq) if eq in spec.equations else equations.index(eq)
                raise ConfigError(f"model.equations[{where}]", f"simulation cannot give {unknown}: "
                                  "only simulated states, inputs, measured states and t can be read")
        texts, functions, allowed = [], [], []
        for eq in equations:
            indices = []
            for f in eq.adjustments:
                if f.text not in texts:
                    texts.append(f.text)
                    functions.append(f)
                indices.append(texts.index(f.text))
            allowed.extend(tuple(indices[j] for j in eq.allowed(i)) for i in eq.adjustable)
        adjustable = tuple((e, i) for e, eq in enumerate(equations) for i in eq.adjustable)
        fixed = tuple((e, i) for e, eq in enumerate(equations) for i in eq.fixed)
        return cls(states, tuple(equations), tuple(external), tuple(source), adjustable, fixed, tuple(functions),
                   tuple(allowed))

    def choices(self, device=None) -> torch.Tensor:
        """Every candidate: one allowed function per adjustable component, (C, Qa)."""
        return torch.tensor(list(itertools.product(*self.allowed)), dtype=torch.long, device=device)

    @property
    def unadjusted(self) -> int:
        """The function index that leaves a component as it is (the starting model)."""
        return len(self.functions)

    def values(self, t, x: torch.Tensor, external: torch.Tensor) -> dict:
        """Signals at time ``t`` from states ``x`` (..., S) and external values (..., E)."""
        values = {"t": t}
        values.update(zip(self.states, x.unbind(-1)))
        values.update(zip(self.external, external.unbind(-1)))
        return values

    def functions_at(self, values: dict, shape) -> torch.Tensor:
        """Adjustment functions (..., G)."""
        return _stack([f(values) for f in self.functions], shape, values["t"].dtype)

    @cached_property
    def columns(self) -> "Columns":
        """The layout of the signal matrix Eq. 9 reads (see :class:`Columns`)."""
        components = [self.equations[e].components[i].term for e, i in self.adjustable + self.fixed]
        distinct = {x.text: x for x in (*self.functions, *components) if x.text not in self.states}
        inner = tuple(x for x in distinct.values() if x.names & set(self.states))
        outer = tuple(x for x in distinct.values() if not x.names & set(self.states))
        order = list(self.states) + [x.text for x in inner + outer] + [None]
        return Columns(inner, outer, tuple(order.index(f.text) for f in self.functions) + (len(order) - 1,),
                       tuple(order.index(x.text) for x in components))

    def equation_rates(self, p: Parameters, dtype, device):
        """``rates(values, shape)``: every equation's modelled target (*shape, E) by Eq. 9, with
        the constants of ``p`` bound once; ``shape`` is the signals' batch shape, ending in p's B
        rows or broadcastable to them."""
        eq9 = _Eq9(self, p, dtype, device, kinematic=False)
        return lambda values, shape: eq9(self._signals(values, shape, dtype), shape)

    def rhs(self, p: Parameters, dtype, device):
        """``rates(values, x)``: ``d x / dt`` (B, S) from the equations (Eq. 9) and the kinematic states."""
        eq9 = _Eq9(self, p, dtype, device, kinematic=True)
        return lambda values, x: eq9(self._signals(values, x.shape[:-1], dtype), x.shape[:-1])

    def stage_rates(self, p: Parameters, t: torch.Tensor, external: torch.Tensor, segments: int = 1):
        """``rate(j, x)``: ``d x / dt`` (B, S) at the j-th of the times ``t`` (K,), the external
        signals there being ``external`` (K, E) or (B, K, E). The expressions that read no state
        are tabulated over all K times at once; a stage evaluates only the others. With
        ``segments`` > 1 the times are that many consecutive segments run side by side: ``x`` is
        (B, segments, S) and ``j`` a stage of each segment (K / segments of them)."""
        b, dtype, columns = p.theta.shape[0], t.dtype, self.columns
        eq9 = _Eq9(self, p, dtype, t.device, kinematic=True)
        signals = self.values(t, t.new_zeros(t.shape + (0,)), external)
        one = _constant(torch.ones((), dtype=dtype, device=t.device), p.theta)
        by_stage = lambda v, axis: (v if segments == 1 else v.unflatten(axis, (segments, -1))).unbind(axis)
        shared = external.dim() == 2  # the same signals for every row: one (K, O + 1) table, read as expanded views
        table = _stack([x(signals) for x in columns.outer] + [one], t.shape if shared else (b, t.shape[0]), dtype)
        tabulated = by_stage(table, -2)  # per stage (B, [segments,] O + 1), or without B where shared
        if shared:
            tabulated = [row.expand((b,) + row.shape) for row in tabulated]
        if not columns.inner:
            return lambda j, x: eq9(torch.cat([x, tabulated[j]], -1), x.shape[:-1])
        read = sorted(set().union(*(x.names for x in columns.inner)) - set(self.states))
        at = [dict(zip(read, v)) for v in zip(*(by_stage(signals[n], -1) for n in read))] if read \
            else [{}] * len(tabulated)

        def rate(j: int, x: torch.Tensor) -> torch.Tensor:
            values = dict(zip(self.states, x.unbind(-1)), **at[j])
            inner = _stack([f(values) for f in columns.inner], x.shape[:-1], dtype)
            return eq9(torch.cat([x, inner, tabulated[j]], -1), x.shape[:-1])

        return rate

    def _signals(self, values: dict, shape, dtype) -> torch.Tensor:
        """The signal matrix (*shape, K) of :class:`Columns` from named values."""
        columns = self.columns
        expressions = [*(values[s] for s in self.states), *(x(values) for x in columns.inner + columns.outer), 1.0]
        return _stack(expressions, shape, dtype)


@dataclass(frozen=True)
class Columns:
    """Where Eq. 9 reads its signals: one matrix whose columns are the simulated states, the
    distinct expressions (adjustment functions and terms) that read a state (``inner``), those
    that read none (``outer``: the solver tabulates them once over all its stage times), and the
    constant 1 an unadjusted component is raised to a power of (factor 1 for any exponent)."""

    inner: tuple
    outer: tuple
    functions: tuple[int, ...]  # column of each adjustment function (G), then of the constant 1
    terms: tuple[int, ...]  # column of each adjustable component's term (Qa), then each fixed one's (P)


class _Eq9:
    """Eq. 9 on a signal matrix v (*shape, K) laid out by :class:`Columns`, the constants of ``p``
    bound once per batch shape: ``sum_i theta_i M_i f_i^gamma_i + sum_j theta_j M_j`` per
    equation, or (``kinematic``) the rate of every simulated state (an equation's target, or the
    state that holds its derivative). The operations and their order are those of the per-call
    formulation (products per component, then sums per equation), so the results are the same
    to the last bit however the signals were gathered."""

    def __init__(self, model: SystemModel, p: Parameters, dtype, device, kinematic: bool):
        columns = model.columns
        magnitudes = {f.is_magnitude for f in model.functions}
        self.p, self.signed, self.mixed = p, False in magnitudes, len(magnitudes) > 1  # sign(1) = 1 for the constant
        self.function_column = torch.tensor(columns.functions, device=device)[p.choice]  # (B, Qa)
        self.inverse_scale = torch.gather(torch.nn.functional.pad(1.0 / p.scale, (0, 1), value=1.0), -1, p.choice)
        self.magnitude = torch.tensor([f.is_magnitude for f in model.functions] + [True], device=device)[p.choice]
        q = len(model.adjustable)
        self.terms = torch.tensor(columns.terms[:q], dtype=torch.long, device=device)
        self.fixed_terms = torch.tensor(columns.terms[q:], dtype=torch.long, device=device)

        def assign(components):  # component -> equation
            matrix = torch.zeros(len(components), len(model.equations), dtype=dtype, device=device)
            for k, (e, _) in enumerate(components):
                matrix[k, e] = 1.0
            return matrix

        self.assign_adjustable, self.assign_fixed = assign(model.adjustable), assign(model.fixed)
        s = len(model.states)  # the rates from cat(states, equations), or the equations' alone when they give every state's
        self.source = None if not kinematic or model.source == tuple(range(s, s + len(model.equations))) \
            else torch.tensor(model.source, device=device)
        self.bound: dict = {}

    def constants(self, shape):
        if shape not in self.bound:
            p = self.p
            rows = (lambda v: v) if len(shape) == 1 else (lambda v: v.view(v.shape[:1] + (1,) * (len(shape) - 1) + v.shape[1:]))
            self.bound[shape] = (rows(self.function_column).expand(shape + self.function_column.shape[-1:]),
                                 rows(self.inverse_scale), rows(self.magnitude), rows(p.gamma), rows(p.theta),
                                 rows(p.theta_fixed))
        return self.bound[shape]

    def __call__(self, v: torch.Tensor, shape) -> torch.Tensor:
        column, inverse_scale, magnitude, gamma, theta, theta_fixed = self.constants(shape)
        f = torch.gather(v, -1, column) * inverse_scale  # exact where the scale is 1 (normalize: none)
        factor = power(torch.log((f.abs() if self.signed else f).clamp_min(FLOOR)), gamma)  # f >= 0 for abs(...)
        if self.signed:  # |f|^gamma for abs(...), sign(f) |f|^gamma otherwise
            factor = factor * (torch.where(magnitude, 1.0, torch.sign(f)) if self.mixed else torch.sign(f))
        out = (torch.index_select(v, -1, self.terms) * factor * theta) @ self.assign_adjustable
        if self.fixed_terms.shape[0]:
            out = out + (torch.index_select(v, -1, self.fixed_terms) * theta_fixed) @ self.assign_fixed
        if self.source is None:
            return out
        return torch.index_select(torch.cat([v[..., : self.source.shape[0]], out], -1), -1, self.source)


def _constant(value: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``value`` as a dual tensor with zero tangent where ``like`` is dual (forward mode takes a
    slow path for an operation between a dual tensor and a plain one)."""
    return value if forward_ad.unpack_dual(like).tangent is None else forward_ad.make_dual(value, torch.zeros_like(value))


def _stack(items: list, shape, dtype) -> torch.Tensor:
    """Stack values that may be numbers or tensors broadcastable to ``shape``: (*shape, K)."""
    tensors = [v if torch.is_tensor(v) and v.shape == shape else torch.as_tensor(v, dtype=dtype).expand(shape)
               for v in items]
    return torch.stack(tensors, -1)


def groups(spec: ModelSpec, coupling: str) -> list[tuple[Equation, ...]]:
    """The equations simulated together: all of them (joint), or one at a time (separate)."""
    return [spec.equations] if coupling == "joint" else [(eq,) for eq in spec.equations]


def build_model(spec: ModelSpec, group: tuple[Equation, ...]) -> SystemModel:
    """The group's states are simulated; inputs and every other state are read from the data."""
    bases = {split_derivative(eq.target)[0] for eq in group}
    external = tuple(spec.inputs) + tuple(s for s in spec.states if split_derivative(s)[0] not in bases)
    return SystemModel.build(spec, group, external)
