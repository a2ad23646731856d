"""Free-run simulation of a (adapted) model with torchdiffeq, from a measured initial state under
measured (linearly interpolated) inputs.

The algebraic evaluation of MSAM (one-step: predict a derivative from estimated states) can look
good while the simulated model drifts or diverges (design.md section 3); this module integrates
the model itself. A model is the spec's state equations, each as an :class:`EquationModel` with
its selected adjustment functions, exponents and theta, batched over ``B`` parameter sets that
are integrated together.

States whose derivative is itself a state (``x`` with ``x_dot``) follow kinematically; every other
state needs an equation whose target is its derivative. Components may read states, inputs, the
time ``t`` and the targets' lower derivatives; anything else (an input's derivative) raises
:class:`~msam_torch.errors.MSAMError`. A trajectory that leaves ``blowup`` times the measured range
is frozen and returned as NaN (marked diverged) so one bad member cannot stall the batch.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Mapping, Sequence

import torch
from torchdiffeq import odeint

from .candidates import FLOOR
from .errors import MSAMError
from .spec import Equation, ModelSpec, derivative_name, split_derivative

LOG_FLOOR = math.log(FLOOR)


@dataclass(frozen=True)
class EquationModel:
    """One state equation ready to simulate, batched over B parameter sets.

    ``yhat = sum_i theta_i M_i g_i(f) + sum_j theta_fixed_j M_j`` (Eq. 6, 9) with
    ``g_i = |f/scale|^gamma_i`` (magnitude functions) or ``sign(f)|f/scale|^gamma_i``, and
    ``g_i = 1`` where ``choice`` is -1 (component left as in the starting model).
    Shapes: ``choice`` (B, Q) long; ``gamma``, ``theta`` (B, Q); ``theta_fixed`` (B, P);
    ``scale`` (F,) the normalisation of the adjustment functions (ones if none).
    """

    equation: Equation
    choice: torch.Tensor
    gamma: torch.Tensor
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    scale: torch.Tensor

    @classmethod
    def starting(cls, equation: Equation, theta: torch.Tensor) -> "EquationModel":
        """The unadjusted model with theta (B, Q + P) over all components in spec order."""
        theta = theta if theta.dim() == 2 else theta.unsqueeze(0)
        b, q = theta.shape[0], len(equation.adjustable)
        return cls(equation, torch.full((b, q), -1, dtype=torch.long, device=theta.device),
                   theta.new_zeros(b, q), theta[:, list(equation.adjustable)], theta[:, list(equation.fixed)],
                   theta.new_ones(len(equation.adjustments)))

    @cached_property
    def _constants(self) -> dict:
        """Per-slot tensors shaped (B, Q), computed once (the model is immutable)."""
        index = self.choice.clamp_min(0)
        magnitude = torch.tensor([a.is_magnitude for a in self.equation.adjustments], device=index.device)[index]
        return {"index": index, "magnitude": magnitude, "log_scale": self.scale.log()[index],
                "unadjusted": self.choice < 0}

    def rate(self, values: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The modelled target derivative (B, ...) for signal values broadcastable to (B, ...)."""
        like = next(v for v in values.values() if torch.is_tensor(v))
        b = self.choice.shape[0]

        def evaluate(expression):
            value = expression(values)
            return value if torch.is_tensor(value) else torch.full_like(like, float(value))

        def stacked(expressions):
            out = torch.stack(torch.broadcast_tensors(*[evaluate(e) for e in expressions]), -1)
            return out.expand((b,) + out.shape[1:]) if out.shape[0] == 1 else out

        eq, c = self.equation, self._constants
        functions = stacked(eq.adjustments)  # (B, ..., F)
        terms = stacked([eq.components[i].term for i in eq.adjustable])  # (B, ..., Q)
        shape = (b,) + (1,) * (terms.dim() - 2) + (-1,)
        view = (lambda x: x) if terms.dim() == 2 else (lambda x: x.view(shape))
        f = functions.gather(-1, view(c["index"]).expand(terms.shape))
        log_f = (torch.log(f.abs()) - view(c["log_scale"])).clamp_min(LOG_FLOOR)
        g = torch.exp((view(self.gamma) * log_f).clamp(max=300.0))
        g = torch.where(view(c["magnitude"]), g, torch.sign(f) * g)
        g = torch.where(view(c["unadjusted"]), 1.0, g)
        total = (view(self.theta) * terms * g).sum(-1)
        if eq.fixed:
            fixed = stacked([eq.components[i].term for i in eq.fixed])
            total = total + (view(self.theta_fixed) * fixed).sum(-1)
        return total


def interpolate(t_grid: torch.Tensor, values: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of ``values`` (..., N) on a uniform grid at scalar time ``t`` (held at the ends)."""
    n = t_grid.shape[0]
    position = ((t - t_grid[0]) / (t_grid[1] - t_grid[0])).clamp(0, n - 1)
    k = position.floor().long().clamp(max=n - 2)
    w = position - k
    return values[..., k] * (1 - w) + values[..., k + 1] * w


def simulate(spec: ModelSpec, models: Sequence[EquationModel], t: torch.Tensor,
             inputs: Mapping[str, torch.Tensor], initial: Mapping[str, torch.Tensor | float],
             method: str = "rk4", step: float | None = None, rtol: float = 1e-6, atol: float = 1e-9,
             blowup: float = 1e3, scale: Mapping[str, float] | None = None) -> dict[str, torch.Tensor]:
    """Integrate the model from ``initial`` (each state (B,) or scalar) over the uniform grid
    ``t`` (N,) under ``inputs`` (each (N,) or (B, N)); return every state as (B, N), NaN where
    diverged (beyond ``blowup`` times ``scale``, each state's typical magnitude, default
    ``max(|initial|, 1)``). ``method``: a torchdiffeq solver; fixed-step solvers (the default
    ``rk4``) step by ``step`` (default: the sampling period times ``N // 500``, so a record costs
    about 500 steps), adaptive ones use ``rtol`` and ``atol``."""
    by_target = {m.equation.target: m for m in models}
    b = max(m.theta.shape[0] for m in models)
    dtype, device = t.dtype, t.device
    rates = []
    for name in spec.states:
        base, order = split_derivative(name)
        derivative = derivative_name(base, order + 1) if order < 2 else None
        if derivative in spec.states:
            rates.append(("state", spec.states.index(derivative)))
        elif derivative in by_target:
            rates.append(("model", by_target[derivative]))
        else:
            raise MSAMError(f"cannot simulate: state {name!r} has no equation for {derivative!r} and no state holds it")
    allowed = set(spec.states) | set(spec.inputs) | {"t"}
    for m in models:
        for c in m.equation.components:
            extra = c.term.names - allowed - set(by_target)
            for f in m.equation.adjustments:
                extra |= f.names - allowed - set(by_target)
            if extra:
                raise MSAMError(f"cannot simulate {m.equation.target!r}: it reads {sorted(extra)}, which are neither "
                                "states, inputs nor simulated derivatives")
    y0 = torch.stack([torch.as_tensor(initial[s], dtype=dtype, device=device).expand(b) for s in spec.states], -1)
    table = {k: torch.as_tensor(v, dtype=dtype, device=device) for k, v in inputs.items()}
    typical = torch.tensor([abs(float((scale or {}).get(s, 0.0))) for s in spec.states], dtype=dtype, device=device)
    span = torch.maximum(y0.abs().amax(0).clamp_min(1.0) if scale is None else y0.abs().amax(0), typical) * blowup

    def rhs(time, state):
        values = {s: state[:, i] for i, s in enumerate(spec.states)}
        values.update({k: interpolate(t, v, time).expand(b) for k, v in table.items()})
        values["t"] = time.expand(b)
        targets = {}
        out = []
        for kind, ref in rates:
            if kind == "state":
                out.append(state[:, ref])
            else:
                rate = ref.rate({**values, **targets})
                targets[ref.equation.target] = rate
                out.append(rate)
        derivative = torch.stack(out, -1)
        alive = (state.abs() < span).all(-1, keepdim=True) & torch.isfinite(derivative).all(-1, keepdim=True)
        return torch.where(alive, derivative, torch.zeros_like(derivative))

    dt = float(t[1] - t[0])
    step = step or dt * max(1, t.shape[0] // 500)
    fixed = method in ("euler", "midpoint", "rk4", "explicit_adams", "implicit_adams")
    with torch.no_grad():
        try:
            trajectory = odeint(rhs, y0, t, method=method, rtol=rtol, atol=atol,
                                options={"step_size": step} if fixed else None)
        except AssertionError:  # torchdiffeq's step-size underflow: integrate with fixed steps instead
            trajectory = odeint(rhs, y0, t, method="rk4", options={"step_size": step})
    diverged = ~((trajectory.abs() < span).all(-1).all(0))  # (B,)
    trajectory = torch.where(diverged.view(1, -1, 1), torch.full_like(trajectory, torch.nan), trajectory)
    return {s: trajectory[..., i].mT for i, s in enumerate(spec.states)}
