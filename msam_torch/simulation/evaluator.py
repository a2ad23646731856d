"""The simulation evaluator of :class:`~msam_torch.engine.trainer.Trainer`: candidates judged by their
simulated outputs (the paper's section 2 alternative to Eq. 6).

The step is Eq. 15-18 on the simulated output: the structural sensitivities are the change
``yhat(Gamma + dgamma e_i) - yhat(Gamma)`` in dM-scaled units (Eq. 16, ``scaling: dm``) or in
exponent units (``gauss_newton``); theta (``theta: varpro``) and the initial states
(``simulation.initial: estimate``) are stepped jointly with the exponents (Gauss-Newton on the
stacked Jacobian). dM (Eq. 15) costs a simulated row per exponent and adjustable theta, so it is
simulated only for the dM-scaled step or the trainer's diagnostics (NaN in the step's result
otherwise). The line search simulates all its step sizes in one batch.
"""
from __future__ import annotations

from dataclasses import replace

import torch

from msam_torch.engine.fitness import correlation, fitness, sum_abs_error
from msam_torch.engine.sensitivity import condition_number, structural_sensitivities
from msam_torch.engine.step import advance, lstsq, step_size
from msam_torch.engine.trainer import measures
from msam_torch.engine.values import Evaluation, State, StepOptions, StepResult
from msam_torch.simulation.least_squares import fit_parameters
from msam_torch.simulation.problem import SimulationData, SimulationSelection, packed, unpacked, usable
from msam_torch.simulation.sensitivities import jacobians


def _initial(selection: SimulationSelection, state: State) -> torch.Tensor:
    if state.initial is not None:
        return state.initial
    initial = selection.data.initial
    return initial.unsqueeze(1).expand(state.gamma.shape[:2] + initial.shape[-1:])


class SimulationEvaluator:
    """Evaluator for :class:`~msam_torch.engine.trainer.Trainer`: candidates judged by their simulation.
    The evaluation of the state a line-search step moved to is kept from its batch, so the
    trainer's evaluation of that state simulates nothing."""

    simulates = True

    def __init__(self):
        self._moved: tuple[State, Evaluation] | None = None

    def evaluate(self, selection: SimulationSelection, state: State, options: StepOptions) -> Evaluation:
        if self._moved is not None and self._moved[0] is state:
            return self._moved[1]
        initial = _initial(selection, state)
        yhat = selection.data.output(state.gamma, selection.choice(state), state.theta, state.theta_fixed, initial,
                                     _probe(selection.data, options))
        return _evaluation(selection, state, yhat, initial)

    def step(self, selection: SimulationSelection, state: State, current: Evaluation, options: StepOptions,
             conditions: bool = True) -> StepResult:
        """Eq. 15-18 on the simulated output, theta and initial states stepped jointly."""
        data = selection.data
        q, p = state.theta.shape[-1], state.theta_fixed.shape[-1]
        z = packed(state, _initial(selection, state))
        free = data.free.clone()
        if not options.theta.re_solved:
            free[: q + p] = False
        if data.refit_steps:  # theta and initial states refitted for the current exponents (variable projection by iteration)
            z, yhat = fit_parameters(data, selection.choice(state), state.gamma, z, free, data.refit_steps)
            current = replace(current, yhat=yhat, fitness=torch.where(state.diverged, current.fitness, fitness(selection.y, yhat)))
        scaled = options.scaling == "dm"
        jac = jacobians(data, selection.choice(state), state.gamma, z, options.dgamma, free, dm=scaled or conditions)
        blown = ~usable(current.yhat).all(-1, keepdim=True)  # (T, C, 1): its simulation left the float range
        eps = torch.where(blown, torch.zeros_like(current.yhat), selection.y - current.yhat)
        phi_scaled = structural_sensitivities(jac.change, jac.dm) if scaled or conditions else None
        phi_unscaled = structural_sensitivities(jac.change, torch.full_like(jac.dm, options.dgamma))
        phi_gamma = phi_scaled if scaled else phi_unscaled
        phi = torch.where(blown.unsqueeze(-1), 0.0, torch.cat([phi_gamma, jac.z[..., free]], -1))
        delta = lstsq(phi, eps, options.damping, options.rcond)
        delta_gamma, delta_z = delta[..., :q], torch.zeros_like(z)
        delta_z[..., free] = delta[..., q:]
        line = LineSearch(selection, state, z, delta_gamma, delta_z, getattr(options.step_size, "steps", ()),
                          _probe(data, options))
        mu = step_size(current.fitness, (phi @ delta.unsqueeze(-1)).squeeze(-1), eps, options, line.fitness)
        gamma, diverged = advance(state.gamma, mu, delta_gamma, state.diverged, current.fitness, options)
        new_z = torch.where(diverged.unsqueeze(-1), z, z + mu.unsqueeze(-1) * delta_z)
        theta, theta_fixed, new_initial = unpacked(new_z, q, p)
        new_state = State(gamma, theta, theta_fixed, diverged, new_initial)
        if line.outputs:
            yhat = current.yhat
            for m, out in line.outputs.items():
                yhat = torch.where(((mu == m) & ~diverged).unsqueeze(-1), out, yhat)
            self._moved = (new_state, _evaluation(selection, new_state, yhat, new_initial))
        cond_scaled, cond_unscaled = (condition_number(phi_scaled), condition_number(phi_unscaled)) if conditions else (None, None)
        return StepResult(new_state, mu, delta_gamma, jac.dm, cond_scaled, cond_unscaled)

    @staticmethod
    def starting_measures(data: SimulationData, theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
        """Measures of the unadjusted starting model (theta as given, initial states of ``data``)."""
        yhat = data.output(torch.zeros_like(theta), torch.full_like(theta, data.model.unadjusted, dtype=torch.long),
                           theta, theta_fixed, data.initial)
        return measures(data.y, yhat)


def _probe(data: SimulationData, options: StepOptions) -> float:
    """The exponent shift whose rows an evaluation integrates with its own for the next step's
    structural sensitivities (Eq. 16): ``dgamma``, unless theta and the initial states are
    refitted first (the step then starts elsewhere)."""
    return 0.0 if data.refit_steps else options.dgamma


def _evaluation(selection: SimulationSelection, state: State, yhat: torch.Tensor, initial: torch.Tensor) -> Evaluation:
    y = selection.y
    score = torch.where(state.diverged, torch.full_like(state.diverged, -torch.inf, dtype=yhat.dtype), fitness(y, yhat))
    return Evaluation(yhat.new_zeros(yhat.shape[:2] + (0, 0)), yhat, state.theta, state.theta_fixed, score,
                      sum_abs_error(y, yhat), correlation(yhat, y), initial)


class LineSearch:
    """``fitness(mu, among)`` of the step rule: the fitness (T, C) of every candidate moved by
    ``mu``. The first call simulates that step size and every smaller one of the backtracking
    ladder (the step rule's ``steps``) in one batch; the later calls read them (``outputs``: mu ->
    simulated outputs). ``probe``: see :meth:`SimulationData.output`."""

    def __init__(self, selection: SimulationSelection, state: State, z, delta_gamma, delta_z, ladder=(), probe=0.0):
        self.selection, self.state, self.z, self.delta_gamma, self.delta_z = selection, state, z, delta_gamma, delta_z
        self.ladder, self.probe = tuple(ladder), probe
        self.outputs: dict[float, torch.Tensor] = {}
        self.known: dict[float, torch.Tensor] = {}

    def fitness(self, mu, among):
        if mu not in self.known:
            state, z = self.state, self.z
            q, p = state.theta.shape[-1], state.theta_fixed.shape[-1]
            mus = [m for m in self.ladder if m <= mu] if mu in self.ladder else [mu]
            scale = torch.tensor(mus, dtype=z.dtype, device=z.device).unsqueeze(-1)  # (L, 1)
            gamma = state.gamma.unsqueeze(-2) + scale * self.delta_gamma.unsqueeze(-2)  # (T, C, L, Qa)
            moved = z.unsqueeze(-2) + scale * self.delta_z.unsqueeze(-2)
            choice = self.selection.choice(state).unsqueeze(-2).expand(gamma.shape)
            out = self.selection.data.output(gamma, choice, *unpacked(moved, q, p), self.probe)
            values = fitness(self.selection.y.unsqueeze(-2), out)  # (T, C, L)
            self.known.update({m: values[..., k] for k, m in enumerate(mus)})
            self.outputs.update({m: out[..., k, :] for k, m in enumerate(mus)})
        return self.known[mu]
