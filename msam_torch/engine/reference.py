"""The sequential reference path: one candidate ``nn.Module`` at a time, sensitivities by torch.func.

A literal reading of Eq. 14-20 for a single candidate and a single trial, with no batching and no
shortcuts: parameter sensitivities by ``jacfwd`` at ``Gamma`` and at every ``Gamma + dgamma e_i``
(Eq. 14-15), finite-difference structural sensitivities (Eq. 16), the least-squares step
(Eq. 17-18) by a pseudo-inverse and the step size (Eq. 20, ``mu = 1`` or the line search: the
options' rule applied to this one candidate, its trial fitness from this path). It is
slow on purpose: the tests check the batched engine against it, and ``bench_engine.py`` uses it
as the sequential baseline.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from msam_torch.engine.candidates import Candidate, EquationData
from msam_torch.engine.fitness import fitness
from msam_torch.engine.sensitivity import parameter_sensitivities, structural_sensitivities
from msam_torch.engine.values import StepOptions


@dataclass(frozen=True)
class ReferenceStep:
    """One step of one candidate: new exponents, mu, the solution of Eq. 17, dM, diverged."""

    gamma: torch.Tensor  # (Q,)
    mu: float
    delta: torch.Tensor  # (Q,)
    dm: torch.Tensor  # (Q,)
    diverged: bool


def _with(module: Candidate, gamma=None, theta=None, theta_fixed=None) -> Candidate:
    return Candidate(module.choice, module.theta if theta is None else theta,
                     module.theta_fixed if theta_fixed is None else theta_fixed,
                     module.gamma.detach() if gamma is None else gamma)


def _least_squares(a: torch.Tensor, b: torch.Tensor, damping: float, rcond: float) -> torch.Tensor:
    """Minimum-norm least squares in unit-norm columns (pseudo-inverse), or damped normal equations."""
    norms = torch.linalg.vector_norm(a, dim=0)
    safe = torch.where(norms > 0, norms, torch.ones_like(norms))
    scaled = a / safe
    if damping:
        eye = torch.eye(a.shape[1], dtype=a.dtype, device=a.device)
        x = torch.linalg.solve(scaled.T @ scaled + damping * eye, scaled.T @ b)
    else:  # singular values below sqrt(rcond) * max <=> eigenvalues of the Gram matrix below rcond * max
        x = torch.linalg.pinv(scaled, rtol=rcond**0.5) @ b
    return torch.where(norms > 0, x / safe, torch.zeros_like(x))


def reference_theta(module: Candidate, data: EquationData, rcond: float = 1e-12) -> Candidate:
    """The candidate with theta re-solved by linear least squares for its exponents."""
    design = torch.cat([parameter_sensitivities(module, data)[0], data.fixed_components[0]], -1)
    solution = _least_squares(design, data.y[0], 0.0, rcond)
    q = module.theta.shape[0]
    return _with(module, theta=solution[:q], theta_fixed=solution[q:])


def reference_fitness(module: Candidate, data: EquationData, options: StepOptions) -> float:
    """Eq. 19 of the candidate (theta re-solved first under 'varpro')."""
    if options.theta.re_solved:
        module = reference_theta(module, data, options.rcond)
    return float(fitness(data.y[0], module(data)[0].detach()))


def reference_step(module: Candidate, data: EquationData, options: StepOptions) -> ReferenceStep:
    """One iteration of Eq. 14-18 for one candidate on one trial (``data`` with T = 1)."""
    if options.theta.re_solved:
        module = reference_theta(module, data, options.rcond)
    y = data.y[0]
    gamma = module.gamma.detach()
    q = gamma.shape[0]
    sens = parameter_sensitivities(module, data)[0]  # (N, Q), Eq. 14 at Gamma
    yhat = module(data)[0].detach()
    eps = y - yhat
    dm, columns = [], []
    for i in range(q):
        shifted = _with(module, gamma=gamma + options.dgamma * torch.eye(q, dtype=gamma.dtype, device=gamma.device)[i])
        sens_i = parameter_sensitivities(shifted, data)[0]
        dm.append(torch.linalg.vector_norm(sens_i - sens, dim=-1).sum() / torch.linalg.vector_norm(sens, dim=-1).sum())
        columns.append(shifted(data)[0].detach() - yhat)
    dm = torch.stack(dm)
    delta_yhat = torch.stack(columns, -1)
    if options.theta.re_solved:  # Kaufman: project off the span of every component's column
        design = torch.cat([sens, data.fixed_components[0]], -1)
        delta_yhat = delta_yhat - design @ torch.stack([_least_squares(design, c, 0.0, options.rcond)
                                                        for c in delta_yhat.T], -1)
    steps = dm if options.scaling == "dm" else torch.full_like(dm, options.dgamma)
    phi = structural_sensitivities(delta_yhat, steps)  # Eq. 16
    delta = _least_squares(phi, eps, options.damping, options.rcond)  # Eq. 17
    trial = lambda m, among: torch.tensor(reference_fitness(_with(module, gamma=gamma + m * delta), data, options),
                                          dtype=y.dtype)
    mu = float(options.step_size.mu(fitness(y, yhat), phi @ delta, eps, trial))  # e.g. Eq. 20
    new = gamma + mu * delta  # Eq. 18
    diverged = bool(~torch.isfinite(new).all() or (new.abs() > options.gamma_limit).any())
    return ReferenceStep(gamma if diverged else new, mu, delta, dm, diverged)


def reference_round_robin(data: EquationData, choices: torch.Tensor, theta: torch.Tensor, theta_fixed: torch.Tensor,
                          options: StepOptions, steps: int, start: torch.Tensor | None = None):
    """Stage 1 of Algorithm 1, one candidate after another: each one's best fitness and its gamma."""
    best_fitness, best_gamma = [], []
    for choice in choices:
        module = Candidate(choice, theta, theta_fixed, start)
        best, best_at, diverged = -torch.inf, module.gamma.detach(), False
        for _ in range(steps):
            if diverged:
                break
            result = reference_step(module, data, options)
            diverged = result.diverged
            module = _with(module, gamma=result.gamma)
            score = -torch.inf if diverged else reference_fitness(module, data, options)
            if score > best:
                best, best_at = score, result.gamma
        best_fitness.append(best)
        best_gamma.append(best_at)
    return torch.tensor(best_fitness, dtype=theta.dtype), torch.stack(best_gamma)
