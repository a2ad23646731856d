"""One MSAM iteration on a batch of candidates: the NLS step (Eq. 17-18), its step size (Eq. 20,
``mu = 1`` or backtracking: a :class:`~msam_torch.engine.step_rules.StepSizeRule`) and, optionally, theta
re-solved by linear least squares at every step (variable projection with Kaufman's Jacobian,
design notes section 3).

Everything is a pure function of tensors batched over (trials, candidates).
"""
from __future__ import annotations

from dataclasses import replace

import torch

from msam_torch.engine.candidates import Selection, columns, predict
from msam_torch.engine.fitness import scores
from msam_torch.engine.sensitivity import gram_condition_number, perturbation_magnitude_from_change
from msam_torch.engine.values import Evaluation, State, StepOptions, StepResult


def lstsq(a: torch.Tensor, b: torch.Tensor, damping: float = 0.0, rcond: float = 1e-12) -> torch.Tensor:
    """Rank-tolerant least squares ``argmin ||a x - b||`` batched over leading axes.

    Columns are scaled to unit norm and the normal equations solved by a symmetric
    eigendecomposition with eigenvalues below ``rcond * max`` dropped: on collinear or zero columns
    this is the minimum-norm solution in the scaled columns (so it does not depend on their units).
    ``damping`` adds ``lambda I`` to the scaled normal equations (Levenberg-Marquardt with Marquardt's
    diagonal scaling). a: (..., N, K), b: (..., N).
    """
    return solve_normal(a.mT @ a, (a.mT @ b.unsqueeze(-1)).squeeze(-1), damping, rcond)


def solve_normal(gram: torch.Tensor, rhs: torch.Tensor, damping: float = 0.0, rcond: float = 1e-12) -> torch.Tensor:
    """:func:`lstsq` from its normal equations: ``gram = a^T a`` (..., K, K), ``rhs = a^T b`` (..., K)
    or several right-hand sides (..., K, R). The column norms are ``sqrt(diag(gram))``; a system
    that is not finite (a diverging candidate) gets a nan solution and leaves the rest unaffected."""
    many = rhs.dim() == gram.dim()
    norms = torch.diagonal(gram, dim1=-2, dim2=-1).sqrt()
    inverse = torch.where(norms > 0, norms.reciprocal(), 0.0)  # zero columns get a zero solution
    scaled = gram * inverse.unsqueeze(-1) * inverse.unsqueeze(-2)
    if damping:
        scaled = scaled + damping * torch.eye(gram.shape[-1], dtype=gram.dtype, device=gram.device)
    finite = torch.isfinite(scaled).all(-1).all(-1, keepdim=True)
    scaled = torch.where(finite.unsqueeze(-1), scaled, 0.0)
    column = inverse.unsqueeze(-1) if many else inverse
    x = torch.linalg.pinv(scaled, rtol=rcond, hermitian=True) @ (rhs * column if many else (rhs * inverse).unsqueeze(-1))
    x = x * column if many else x.squeeze(-1) * inverse
    return torch.where(finite.unsqueeze(-1) if many else finite, x, torch.nan)


def _fixed_times(selection: Selection, m: torch.Tensor) -> torch.Tensor:
    """``F^T m`` for the fixed components ``F`` and ``m`` (..., C, N, K): (..., C, P, K)."""
    return selection.fixed_components.mT @ m


def design_gram(selection: Selection, cols: torch.Tensor) -> torch.Tensor:
    """``D^T D`` of the design ``D = [cols, fixed components]`` (..., Q + P, Q + P), assembled
    from its blocks so that ``D`` (the fixed columns copied for every candidate) is never formed."""
    gram = cols.mT @ cols
    if not selection.fixed_components.shape[-1]:
        return gram
    cross = _fixed_times(selection, cols)  # (..., P, Q)
    fixed = selection.fixed_components.mT @ selection.fixed_components
    fixed = fixed.expand(cross.shape[:-2] + fixed.shape[-2:])
    return torch.cat([torch.cat([gram, cross.mT], -1), torch.cat([cross, fixed], -1)], -2)


def design_transpose_times(selection: Selection, cols: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """``D^T m`` for ``m`` (..., N, K): (..., Q + P, K)."""
    top = cols.mT @ m
    if not selection.fixed_components.shape[-1]:
        return top
    fixed = _fixed_times(selection, m)
    return torch.cat([top, fixed.expand(top.shape[:-2] + fixed.shape[-2:])], -2)


def design_times(selection: Selection, cols: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """``D c`` for coefficients (..., Q + P, K): (..., N, K), formed as rows ``c^T D^T`` and
    returned sample-axis last in memory, like ``cols``."""
    q = cols.shape[-1]
    out = coefficients[..., :q, :].mT @ cols.mT
    if selection.fixed_components.shape[-1]:
        out = out + coefficients[..., q:, :].mT @ selection.fixed_components.mT
    return out.mT


def solve_theta(selection: Selection, cols: torch.Tensor, rcond: float = 1e-12, gram: torch.Tensor | None = None):
    """Theta of every component by linear least squares for fixed exponents (``gram``: ``D^T D``
    when already known)."""
    gram = design_gram(selection, cols) if gram is None else gram
    rhs = design_transpose_times(selection, cols, selection.y.unsqueeze(-1)).squeeze(-1)
    solution = solve_normal(gram, rhs, rcond=rcond)
    q = cols.shape[-1]
    return solution[..., :q], solution[..., q:]


def evaluate(selection: Selection, state: State, options: StepOptions) -> Evaluation:
    """Columns, output and fitness of ``state`` (theta re-solved first under 'varpro')."""
    cols = columns(selection, state.gamma)
    theta, theta_fixed, gram = state.theta, state.theta_fixed, None
    if options.theta.re_solved:
        gram = design_gram(selection, cols)
        theta, theta_fixed = solve_theta(selection, cols, options.rcond, gram)
    yhat = predict(selection, cols, theta, theta_fixed)
    score, error, rho = scores(selection.y, yhat)
    score = torch.where(state.diverged, torch.full_like(score, -torch.inf), score)
    return Evaluation(cols, yhat, theta, theta_fixed, score, error, rho, design_gram=gram)


def step(selection: Selection, state: State, current: Evaluation, options: StepOptions,
         conditions: bool = True) -> StepResult:
    """One iteration of Eq. 15-18 (or its variable-projection form) on every candidate.

    With ``Y = theta * [S(Gamma + dgamma e_i) - S(Gamma)]`` the structural sensitivities are
    ``Phi = Y / dM`` (Eq. 16) or ``Y / dgamma``; the least-squares problem of Eq. 17 is solved on
    ``Y`` (the same equilibrated problem) and mapped back, ``Phi dGamma = Y x``. With theta fixed
    only the small Gram matrices ``Y^T Y`` and ``Y^T eps`` are formed; ``conditions`` also returns
    ``cond(Phi^T Phi)`` with and without dM scaling (Figure 5).
    """
    eps = selection.y - current.yhat
    if selection.project is None:  # S(Gamma + dgamma e_i) - S: column i times |f_i|^dgamma - 1
        change = current.cols * selection.perturbation_factor(options.dgamma)
    else:  # projected columns (weak form): perturb, then project
        change = columns(selection, state.gamma + options.dgamma) - current.cols
    dm = perturbation_magnitude_from_change(current.cols, change)
    theta = current.theta
    if options.theta.re_solved:  # Kaufman: project the sensitivities off the span of the columns
        cols = current.cols
        design = design_gram(selection, cols) if current.design_gram is None else current.design_gram
        sens = change * theta.unsqueeze(-2)
        projection = solve_normal(design, design_transpose_times(selection, cols, sens), rcond=options.rcond)
        sens = sens - design_times(selection, cols, projection)
        gram = sens.mT @ sens
        rhs = (sens.mT @ eps.unsqueeze(-1)).squeeze(-1)
        fitted = lambda x: (sens @ x.unsqueeze(-1)).squeeze(-1)
    else:  # Y = change * theta: scale the Gram matrix of ``change`` instead of forming Y
        gram = (change.mT @ change) * (theta.unsqueeze(-1) * theta.unsqueeze(-2))
        rhs = (eps.unsqueeze(-2) @ change).squeeze(-2) * theta  # row forms: along the stored sample axis
        fitted = lambda x: ((theta * x).unsqueeze(-2) @ change.mT).squeeze(-2)
    unit = lambda: torch.full_like(dm, options.dgamma)
    steps = dm if options.scaling == "dm" else unit()  # Phi's column i is Y_i / steps_i
    x = solve_normal(gram, rhs, options.damping, options.rcond)
    delta = x * steps.clamp_min(torch.finfo(dm.dtype).tiny)

    def trial_fitness(mu, among):
        return moved_fitness(selection, state, mu * delta, among, options)

    mu = step_size(current.fitness, fitted(x), eps, options, trial_fitness, state.settled)  # Phi dGamma = Y x
    gamma, diverged = advance(state.gamma, mu, delta, state.diverged, current.fitness, options)
    new_state = State(gamma, current.theta, current.theta_fixed, diverged, settled=options.step_size.settled(mu))
    cond_scaled = cond_unscaled = None
    if conditions:
        cond_scaled = gram_condition_number(_rescale(gram, dm))
        cond_unscaled = gram_condition_number(_rescale(gram, unit()))
    return StepResult(new_state, mu, delta, dm, cond_scaled, cond_unscaled)


def moved_fitness(selection: Selection, state: State, move: torch.Tensor, among: torch.Tensor,
                  options: StepOptions) -> torch.Tensor:
    """Fitness (T, C) of the candidates with exponents ``gamma + move``, evaluated only where
    ``among`` (T, C) holds (elsewhere any value): gathered into a batch of their own when they are
    at most half of the batch, since the evaluation of each candidate is independent of the others."""
    moved = replace(state, gamma=state.gamma + move)
    if selection.project is not None or 2 * int(among.sum()) > among.numel():
        return evaluate(selection, moved, options).fitness
    trials, candidates = among.nonzero(as_tuple=True)
    pick = lambda values: values.expand(among.shape + values.shape[2:])[trials, candidates].unsqueeze(1)
    part = State(pick(moved.gamma), pick(moved.theta), pick(moved.theta_fixed), pick(moved.diverged))
    fitness = torch.full(among.shape, -torch.inf, dtype=move.dtype, device=move.device)
    return fitness.index_put_((trials, candidates), evaluate(selection.take(trials, candidates), part, options).fitness[:, 0])


def _rescale(gram: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
    """``Phi^T Phi`` for ``Phi = Y / steps`` from ``Y^T Y``."""
    steps = steps.clamp_min(torch.finfo(steps.dtype).tiny)
    return gram / (steps.unsqueeze(-1) * steps.unsqueeze(-2))


def advance(gamma: torch.Tensor, mu: torch.Tensor, delta: torch.Tensor, diverged: torch.Tensor,
            fitness: torch.Tensor, options: StepOptions) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 18 ``gamma + mu delta``; candidates whose step is not finite or leaves ``gamma_limit``
    (or whose fitness is not finite) are marked diverged and keep their exponents."""
    new = torch.addcmul(gamma, mu.unsqueeze(-1), delta)
    within = (new.abs() <= options.gamma_limit).all(-1) & torch.isfinite(fitness)  # False for nan too
    diverged = diverged | ~within
    return torch.where(diverged.unsqueeze(-1), gamma, new), diverged


def step_size(fitness: torch.Tensor, predicted: torch.Tensor, eps: torch.Tensor,
              options: StepOptions, trial_fitness, settled: torch.Tensor | None = None) -> torch.Tensor:
    """mu of every candidate (T, C) by ``options.step_size`` (Eq. 20, 1, or a backtracking line
    search; see :meth:`~msam_torch.engine.step_rules.StepSizeRule.mu` for the arguments)."""
    return options.step_size.mu(fitness, predicted, eps, trial_fitness, settled)
