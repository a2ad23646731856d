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

import torch

from ..candidates import FLOOR, power
from ..config import Config
from ..errors import ConfigError
from ..spec import Equation, ModelSpec, derivative_name, split_derivative


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

    def equation_rates(self, p: Parameters, dtype, device):
        """``rates(values, shape)``: every equation's modelled target (*shape, E) by Eq. 9, with
        the constants of ``p`` bound once; ``shape`` is the signals' batch shape, ending in p's B
        rows or broadcastable to them. The unadjusted choice picks an appended constant function 1
        (factor 1 for any exponent)."""
        def assign(components):
            matrix = torch.zeros(len(components), len(self.equations), dtype=dtype, device=device)
            for k, (e, _) in enumerate(components):
                matrix[k, e] = 1.0
            return matrix

        inverse_scale = torch.nn.functional.pad(1.0 / p.scale, (0, 1), value=1.0)
        magnitude = torch.tensor([f.is_magnitude for f in self.functions] + [True], device=device)
        signed = not all(f.is_magnitude for f in self.functions)
        adjustable_terms = [self.equations[e].components[i].term for e, i in self.adjustable]
        fixed_terms = [self.equations[e].components[i].term for e, i in self.fixed]
        assign_adjustable, assign_fixed = assign(self.adjustable), assign(self.fixed)
        bound: dict = {}  # the constants of p per batch shape

        def constants(shape):
            if shape not in bound:
                rows = (lambda v: v) if len(shape) == 1 else (lambda v: v.view(v.shape[:1] + (1,) * (len(shape) - 1) + v.shape[1:]))
                bound[shape] = (rows(p.choice).expand(shape + p.choice.shape[-1:]), rows(p.gamma), rows(p.theta),
                                rows(p.theta_fixed), rows(inverse_scale), rows(inverse_scale[..., -1]).expand(shape))
            return bound[shape]

        def rates(values: dict, shape) -> torch.Tensor:
            cache: dict = {}
            choice, gamma, theta, theta_fixed, inverse_scale_, one = constants(shape)
            f = _stack([_cached(g, values, shape, cache) for g in self.functions] + [one], shape, dtype)
            f = f * inverse_scale_  # exact where the scale is 1 (normalize: none)
            factor = power(torch.gather(torch.log(f.abs().clamp_min(FLOOR)), -1, choice), gamma)
            if signed:
                factor = factor * torch.gather(torch.where(magnitude, torch.ones_like(f), torch.sign(f)), -1, choice)
            terms = _stack([_cached(m, values, shape, cache) for m in adjustable_terms], shape, dtype)
            out = (terms * factor * theta) @ assign_adjustable
            if fixed_terms:
                fixed = _stack([_cached(m, values, shape, cache) for m in fixed_terms], shape, dtype)
                out = out + (fixed * theta_fixed) @ assign_fixed
            return out

        return rates

    def rhs(self, p: Parameters, dtype, device):
        """``rates(values, x)``: ``d x / dt`` (B, S) from the equations (Eq. 9) and the kinematic states."""
        equation_rates = self.equation_rates(p, dtype, device)
        source = torch.tensor(self.source, device=device)
        return lambda values, x: torch.index_select(torch.cat([x, equation_rates(values, x.shape[:-1])], -1), -1, source)


def _cached(expression, values: dict, shape, cache: dict):
    """Evaluate each distinct expression text once per call."""
    if expression.text not in cache:
        cache[expression.text] = expression(values)
    return cache[expression.text]


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


def output_states(config: Config, spec: ModelSpec, model: SystemModel) -> tuple[str, ...]:
    """The simulated states compared with the data (``simulation.output``, else the measured ones)."""
    sim = config.adaptation.simulation
    for i, name in enumerate(sim.output):
        if name not in spec.states:
            raise ConfigError(f"adaptation.simulation.output[{i}]", f"{name!r} is not a state of the model")
    chosen = tuple(o for o in sim.output if o in model.states)
    if not sim.output:
        chosen = tuple(s for s in model.states if s in config.data.columns)
    if not chosen:
        raise ConfigError("adaptation.simulation.output", f"name the measured states among {list(model.states)} "
                          "that the simulation is compared with")
    return chosen


def state_limits(config: Config, states: tuple[str, ...], dtype=torch.float64, device=None) -> torch.Tensor | None:
    """The range of every simulated state (2, S) from ``simulation.saturation`` (None: unbounded);
    ranges of states another group simulates are ignored."""
    saturation = config.adaptation.simulation.saturation
    if not saturation:
        return None
    for name, (low, high) in saturation.items():
        key = f"adaptation.simulation.saturation.{name}"
        if name not in config.model.states:
            raise ConfigError(key, f"{name!r} is not a state of the model")
        if low is not None and high is not None and not low < high:
            raise ConfigError(key, f"the range [{low}, {high}] is empty: give [low, high] with low < high")
    bound = lambda name, k, default: default if saturation.get(name, (None, None))[k] is None else float(saturation[name][k])
    return torch.tensor([[bound(x, 0, -torch.inf) for x in states], [bound(x, 1, torch.inf) for x in states]],
                        dtype=dtype, device=device)
