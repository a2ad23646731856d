"""Equation-by-equation models of a whole spec (the diagnosis's one-step predictions and free runs)
on the one ODE model (:class:`~msam_torch.simulation.ode.SystemModel`) and the one :func:`~.solver.simulate`.

An :class:`EquationModel` is one state equation with its selected adjustment functions, exponents
and theta, batched over ``B`` parameter sets; ``choice`` -1 leaves a component as in the starting
model and ``scale`` (F,) divides the adjustment functions (it is folded into theta:
``theta |f/s|^gamma = theta s^-gamma |f|^gamma``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Mapping, Sequence

import numpy as np
import torch

from msam_torch.errors import MSAMError
from msam_torch.model.spec import Equation, ModelSpec, derivative_name, split_derivative
from msam_torch.simulation.ode import Parameters, SystemModel
from msam_torch.simulation.record import Record
from msam_torch.simulation.solver import simulate


@dataclass(frozen=True)
class EquationModel:
    """``yhat = sum_i theta_i M_i g_i(f) + sum_j theta_fixed_j M_j`` (Eq. 6, 9), g_i = |f/scale|^gamma_i
    (or signed), 1 where ``choice`` is -1. Shapes: ``choice`` (B, Q) long; ``gamma``, ``theta``
    (B, Q); ``theta_fixed`` (B, P); ``scale`` (F,)."""

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

    def parameters(self, model: SystemModel) -> Parameters:
        """The model's :class:`Parameters` for ``model``, whose functions include this equation's."""
        texts = [f.text for f in model.functions]
        lookup = torch.tensor([texts.index(f.text) for f in self.equation.adjustments] + [model.unadjusted],
                              device=self.choice.device)
        index = torch.where(self.choice < 0, len(self.equation.adjustments), self.choice)
        scale = torch.cat([self.scale, self.scale.new_ones(1)])[index]
        theta = self.theta * torch.where(self.choice < 0, 1.0, scale ** (-self.gamma))
        return Parameters(self.gamma, lookup[index], theta, self.theta_fixed,
                          self.theta.new_ones(self.choice.shape[0], len(model.functions)))

    @cached_property
    def _alone(self) -> SystemModel:
        """The equation as a model of its own, every signal it reads external."""
        eq = self.equation
        return SystemModel.build(ModelSpec((), (), {}, (eq,)), (eq,), tuple(sorted(eq.signals - {eq.target, "t"})))

    def rate(self, values: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The modelled target derivative (B, ...) for signal values broadcastable to (B, ...)."""
        shapes = [v.shape for v in values.values() if torch.is_tensor(v)]
        like = next(v for v in values.values() if torch.is_tensor(v))
        shape = (self.choice.shape[0],) + np.broadcast_shapes(*shapes)[1:]  # torch's imports sympy: 1 s
        rates = self._alone.equation_rates(self.parameters(self._alone), like.dtype, like.device)
        return rates(values, shape)[..., 0]


def simulate_equations(spec: ModelSpec, models: Sequence[EquationModel], t: torch.Tensor,
                       inputs: Mapping[str, torch.Tensor], initial: Mapping[str, torch.Tensor | float],
                       method: str = "rk4", step: float | None = None, rtol: float = 1e-6, atol: float = 1e-9,
                       blowup: float = 1e3, scale: Mapping[str, float] | None = None,
                       held: Sequence[str] = ()) -> dict[str, torch.Tensor]:
    """Integrate every state of ``spec`` from ``initial`` (each (B,) or scalar) over the uniform grid
    ``t`` (N,) under ``inputs`` (each (N,) or (B, N); the ``held`` ones held between samples, else
    interpolated linearly): each state (B, N), NaN where diverged (beyond
    ``blowup`` times ``scale``, each state's typical magnitude, default ``max(|initial|, 1)``).
    Fixed-step solvers step by ``step`` (default: the sampling period times ``N // 500``, about
    500 steps a record); adaptive ones use ``rtol`` and ``atol``."""
    equations = tuple(m.equation for m in models)
    targets = {eq.target for eq in equations}
    for name in spec.states:
        base, order = split_derivative(name)
        derivative = derivative_name(base, order + 1)
        if derivative not in spec.states and derivative not in targets:
            raise MSAMError(f"model.equations: cannot simulate: state {name!r} has no equation for {derivative!r} and "
                            "no state holds it (add the equation, or skip the free runs: --no-free-run)")
    model, p, b = _system(spec, models)
    dtype, device = t.dtype, t.device
    y0 = torch.stack([torch.as_tensor(initial[s], dtype=dtype, device=device).expand(b) for s in model.states], -1)
    table = [torch.as_tensor(inputs[u], dtype=dtype, device=device) for u in model.external]
    batched = any(v.dim() == 2 for v in table)
    external = torch.stack([v.expand(b, -1) if batched else v for v in table], -1) if table else \
        torch.zeros(t.shape[0], 0, dtype=dtype, device=device)
    record = Record(t, external, t.new_zeros(0, t.shape[0]), y0[0],
                    held=torch.tensor([u in held for u in model.external], dtype=torch.bool, device=device))
    typical = torch.tensor([abs(float((scale or {}).get(s, 0.0))) for s in model.states], dtype=dtype, device=device)
    span = torch.maximum(y0.abs().amax(0).clamp_min(1.0) if scale is None else y0.abs().amax(0), typical) * blowup
    step = step or float(t[1] - t[0]) * max(1, t.shape[0] // 500)
    with torch.no_grad():
        states = simulate(model, record, p, y0, method, limits=None, span=span, step=step, rtol=rtol, atol=atol)
    return {s: states[..., i] for i, s in enumerate(model.states)}


def fastest_decay(spec: ModelSpec, models: Sequence[EquationModel], points: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """The largest magnitude of the decaying modes of each row (B,): the eigenvalues with negative
    real part of the Jacobian ``d(dx/dt)/dx`` of the whole model at each of the K ``points`` (``t``,
    every simulated state and input, each (K,)), the median over the points (0 without any). The
    rows of the Jacobian by reverse mode, one per state (every point's rate depends on its own state
    alone): torch's forward mode imports its compiler on first use, a second of start-up. An explicit
    fixed-step solver is stable on a mode only while the step times its magnitude lies within the
    method's interval (:data:`~.solver.STABILITY`); a growing mode (positive real part) diverges at any step. The median, not the greatest: a
    bounded law with an unbounded slope (Coulomb friction's ``w|w|^-0.9`` near ``w = 0``) makes a
    fixed step chatter where the slope is steep, not diverge."""
    model, p, b = _system(spec, models)
    k = points["t"].shape[0]
    x = torch.stack([points[s] for s in model.states], -1).repeat(b, 1, 1)  # (B, K, S)
    external = torch.stack([points[u] for u in model.external], -1).expand(b, k, -1) if model.external \
        else x.new_zeros(b, k, 0)
    rhs = model.rhs(p, x.dtype, x.device)
    rate = lambda x: rhs(model.values(points["t"].expand(b, k), x, external), x)
    with torch.enable_grad():
        x = x.detach().requires_grad_()
        rates = rate(x)
        rows = [torch.autograd.grad(rates[..., i].sum(), x, retain_graph=True, allow_unused=True)[0]
                if rates.requires_grad else None for i in range(x.shape[-1])]
    rows = torch.stack([torch.zeros_like(x) if r is None else r for r in rows], -2).detach()
    eigenvalues = torch.linalg.eigvals(rows.nan_to_num(0.0, 0.0, 0.0))  # (B, K, S)
    decaying = torch.where(eigenvalues.real < 0, eigenvalues.abs(), torch.zeros_like(eigenvalues.real))
    return decaying.amax(-1).median(-1).values


def _system(spec: ModelSpec, models: Sequence[EquationModel]) -> tuple[SystemModel, Parameters, int]:
    """The one ODE model of ``models``' equations (every input external) and their parameters,
    rows broadcast to the largest batch B."""
    model = SystemModel.build(spec, tuple(m.equation for m in models), tuple(spec.inputs))
    b = max(m.theta.shape[0] for m in models)
    rows = [m.parameters(model) for m in models]
    cat = lambda name: torch.cat([getattr(r, name).expand(b, -1) for r in rows], -1)
    return model, Parameters(cat("gamma"), cat("choice"), cat("theta"), cat("theta_fixed"),
                             rows[0].scale.expand(b, -1)), b
