"""One MSAM iteration on a batch of candidates: the NLS step (Eq. 17-18), its step size (Eq. 20,
``mu = 1`` or backtracking) and, optionally, theta re-solved by linear least squares at every
step (variable projection with Kaufman's Jacobian, design notes section 3).

Everything is a pure function of tensors batched over (trials, candidates).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from .candidates import Selection, columns, predict
from .fitness import correlation, fitness, sum_abs_error
from .sensitivity import condition_number, perturbation_magnitude, structural_sensitivities

LINE_SEARCH_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125)


@dataclass(frozen=True)
class StepOptions:
    """How a step is taken. Defaults follow the paper (section 4)."""

    dgamma: float = 1e-2  # exponent perturbation of Eq. 15-16
    scaling: str = "dm"  # 'dm': solve and step in dM-scaled units (Eq. 16-18); 'gauss_newton'
    step_size: str = "eq20"  # 'eq20' (mu = corr(eps, Phi dGamma)), 'one', 'line_search'
    theta: str = "fixed"  # 'fixed' nominal theta, or 'varpro' (theta re-solved every step)
    damping: float = 0.0  # Levenberg-Marquardt damping on the column-equilibrated normal equations
    gamma_limit: float = 20.0  # |gamma| beyond which a candidate is marked diverged
    rcond: float = 1e-12  # relative eigenvalue cut-off of the least-squares solves


@dataclass(frozen=True)
class State:
    """Exponents and theta of a batch of candidates: (T, C, Q), (T, C, Q), (T, C, P), (T, C).

    ``initial`` (T, C, S): estimated initial states, used by simulation-based evaluation only.
    """

    gamma: torch.Tensor
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    diverged: torch.Tensor
    initial: torch.Tensor | None = None


@dataclass(frozen=True)
class Evaluation:
    """A state evaluated on the data: columns, output, error and fitness (Eq. 19)."""

    cols: torch.Tensor  # (T, C, N, Q)
    yhat: torch.Tensor  # (T, C, N)
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    fitness: torch.Tensor  # (T, C)
    sum_abs_error: torch.Tensor
    rho: torch.Tensor
    initial: torch.Tensor | None = None  # (T, C, S) initial states simulated from (simulation mode)


@dataclass(frozen=True)
class StepResult:
    """The new state and what the step saw: mu, the solution, dM and condition numbers."""

    state: State
    mu: torch.Tensor  # (T, C)
    delta: torch.Tensor  # (T, C, Q) the least-squares solution of Eq. 17
    dm: torch.Tensor  # (T, C, Q) Eq. 15
    cond_scaled: torch.Tensor  # (T, C) cond(Phi^T Phi) with dM scaling
    cond_unscaled: torch.Tensor  # (T, C) without


def lstsq(a: torch.Tensor, b: torch.Tensor, damping: float = 0.0, rcond: float = 1e-12) -> torch.Tensor:
    """Rank-tolerant least squares ``argmin ||a x - b||`` batched over leading axes.

    Columns are equilibrated, the normal equations solved by a symmetric eigendecomposition with
    eigenvalues below ``rcond * max`` dropped (minimum-norm solution on collinear or zero
    columns), and ``damping`` adds ``lambda I`` (Levenberg-Marquardt). a: (..., N, K), b: (..., N).
    """
    norms = torch.linalg.vector_norm(a, dim=-2)
    safe = torch.where(norms > 0, norms, torch.ones_like(norms))
    scaled = a / safe.unsqueeze(-2)
    gram = scaled.mT @ scaled
    if damping:
        gram = gram + damping * torch.eye(gram.shape[-1], dtype=gram.dtype, device=gram.device)
    rhs = (scaled.mT @ b.unsqueeze(-1)).squeeze(-1)
    values, vectors = torch.linalg.eigh(gram)
    keep = values > rcond * values[..., -1:].clamp_min(torch.finfo(a.dtype).tiny)
    inverse = torch.where(keep, 1.0 / torch.where(keep, values, torch.ones_like(values)), torch.zeros_like(values))
    x = (vectors @ (inverse * (vectors.mT @ rhs.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
    return torch.where(norms > 0, x / safe, torch.zeros_like(x))


def solve_theta(selection: Selection, cols: torch.Tensor, rcond: float = 1e-12):
    """Theta of every component by linear least squares for fixed exponents."""
    design = torch.cat([cols, selection.fixed_components.expand(cols.shape[:-1] + (-1,))], -1)
    solution = lstsq(design, selection.y.expand(cols.shape[:-1]), rcond=rcond)
    q = cols.shape[-1]
    return solution[..., :q], solution[..., q:]


def evaluate(selection: Selection, state: State, options: StepOptions) -> Evaluation:
    """Columns, output and fitness of ``state`` (theta re-solved first under 'varpro')."""
    cols = columns(selection, state.gamma)
    theta, theta_fixed = state.theta, state.theta_fixed
    if options.theta == "varpro":
        theta, theta_fixed = solve_theta(selection, cols, options.rcond)
    yhat = predict(selection, cols, theta, theta_fixed)
    score = torch.where(state.diverged, torch.full_like(state.diverged, -torch.inf, dtype=yhat.dtype), fitness(selection.y, yhat))
    return Evaluation(cols, yhat, theta, theta_fixed, score, sum_abs_error(selection.y, yhat), correlation(yhat, selection.y))


def step(selection: Selection, state: State, current: Evaluation, options: StepOptions) -> StepResult:
    """One iteration of Eq. 15-18 (or its variable-projection form) on every candidate."""
    eps = selection.y - current.yhat
    perturbed = columns(selection, state.gamma + options.dgamma)
    delta_cols = perturbed - current.cols
    dm = perturbation_magnitude(current.cols, perturbed)
    delta_yhat = current.theta.unsqueeze(-2) * delta_cols
    if options.theta == "varpro":  # Kaufman: project the sensitivities off the span of the columns
        design = torch.cat([current.cols, selection.fixed_components.expand(current.cols.shape[:-1] + (-1,))], -1)
        delta_yhat = delta_yhat - design @ _lstsq_many(design, delta_yhat, options.rcond)
    unit = torch.full_like(dm, options.dgamma)
    phi_scaled = structural_sensitivities(delta_yhat, dm)
    phi_unscaled = structural_sensitivities(delta_yhat, unit)
    phi = phi_scaled if options.scaling == "dm" else phi_unscaled
    delta = lstsq(phi, eps, options.damping, options.rcond)

    def trial_fitness(mus):  # (L,) -> (L, T, C)
        gamma = state.gamma + mus.view((-1,) + (1,) * state.gamma.dim()) * delta
        return evaluate(selection, replace(state, gamma=gamma), options).fitness

    mu = step_size(current.fitness, phi, delta, eps, options, trial_fitness)
    gamma, diverged = advance(state.gamma, mu, delta, state.diverged, current.fitness, options)
    new_state = State(gamma, current.theta, current.theta_fixed, diverged)
    return StepResult(new_state, mu, delta, dm, condition_number(phi_scaled), condition_number(phi_unscaled))


def advance(gamma: torch.Tensor, mu: torch.Tensor, delta: torch.Tensor, diverged: torch.Tensor,
            fitness: torch.Tensor, options: StepOptions) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 18 ``gamma + mu delta``; candidates whose step is not finite or leaves ``gamma_limit``
    (or whose fitness is not finite) are marked diverged and keep their exponents."""
    new = gamma + mu.unsqueeze(-1) * delta
    bad = ~torch.isfinite(new).all(-1) | (new.abs() > options.gamma_limit).any(-1) | ~torch.isfinite(fitness)
    diverged = diverged | bad
    return torch.where(diverged.unsqueeze(-1), gamma, new), diverged


def _lstsq_many(a: torch.Tensor, b: torch.Tensor, rcond: float) -> torch.Tensor:
    """Least squares with several right-hand sides ``b`` (..., N, K) -> (..., K_a, K)."""
    return lstsq(a.unsqueeze(-3), b.mT, rcond=rcond).mT


def step_size(fitness: torch.Tensor, phi: torch.Tensor, delta: torch.Tensor, eps: torch.Tensor,
              options: StepOptions, trial_fitness) -> torch.Tensor:
    """mu of every candidate (T, C): Eq. 20, 1, or a backtracking line search.

    ``trial_fitness(mus)`` evaluates the candidates moved by each ``mu`` of ``mus`` (L,) and
    returns their fitness (L, T, C); it is called only by the line search.
    """
    if options.step_size == "eq20":  # Eq. 20
        return correlation(eps, (phi @ delta.unsqueeze(-1)).squeeze(-1))
    if options.step_size == "one":
        return torch.ones_like(fitness)
    return _line_search(fitness, delta, trial_fitness)


def _line_search(fitness, delta, trial_fitness) -> torch.Tensor:
    """Largest mu in LINE_SEARCH_STEPS that raises the fitness (0 if none), all at once."""
    mus = torch.tensor(LINE_SEARCH_STEPS, dtype=delta.dtype, device=delta.device)
    better = trial_fitness(mus) > fitness  # (L, T, C)
    first = torch.where(better.any(0), better.long().argmax(0), torch.full_like(better[0], len(mus), dtype=torch.long))
    return torch.cat([mus, mus.new_zeros(1)])[first]
