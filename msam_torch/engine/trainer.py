"""Algorithm 1: round robin over every candidate, then refinement of the winner.

The trainer owns the loop and fires named events; logging, progress bars and checkpoints are
callbacks (``trainer.add_callback(event, fn)``), each called as ``fn(trainer, **payload)``.
Events: ``round_robin_step``, ``round_robin_end``, ``refinement_step``, ``refinement_end``.
Candidates are processed in chunks of ``chunk_size`` so memory stays bounded; all trials of a
batch (leading axis T) run together. How a candidate is evaluated and stepped is the trainer's
``evaluator`` (:class:`~msam_torch.run.evaluators.Evaluator`): :class:`Algebraic` (Eq. 6, the default)
or the simulation-based evaluator of :mod:`msam_torch.simulation`; the best *state* of each
candidate (exponents, theta and, in simulation mode, initial states) is what the stages keep and
hand on. A loop ends early when a step leaves every candidate of its batch where it was: the step
being a function of the state, every later one would repeat it. ``diagnostics`` switches on the
condition numbers ``cond(Phi^T Phi)`` of every step (Figure 5; ``result.cond_scaled`` /
``cond_unscaled`` in the step events, else None): two eigendecompositions per candidate and step,
so only a listener that records them sets it.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from typing import Callable

import torch

from msam_torch.engine.candidates import EquationData, enumerate_choices
from msam_torch.engine.fitness import correlation, fitness, sum_abs_error
from msam_torch.engine.step import evaluate, step
from msam_torch.engine.values import Evaluator, State, StepOptions


@dataclass(frozen=True)
class Fit:
    """Outcome of Algorithm 1 for one state equation, batched over T trials.

    ``choices`` (C, Q): the adjustment index of every adjustable component per candidate;
    ``ranking_fitness`` (T, C): each candidate's best fitness in the round robin;
    ``winner`` (T,); ``gamma`` (T, Q), ``theta`` (T, Q), ``theta_fixed`` (T, P): the adapted model;
    ``start`` / ``adapted``: dicts of (T,) tensors ``fitness``, ``sum_abs_error``, ``rho``;
    ``diverged`` (T, C): candidates marked and skipped.
    """

    choices: torch.Tensor
    ranking_fitness: torch.Tensor
    ranking_gamma: torch.Tensor
    winner: torch.Tensor
    gamma: torch.Tensor
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    start: dict
    adapted: dict
    diverged: torch.Tensor
    initial: torch.Tensor | None = None  # (T, S) estimated initial states (simulation mode)


def measures(y: torch.Tensor, yhat: torch.Tensor) -> dict:
    return {"fitness": fitness(y, yhat), "sum_abs_error": sum_abs_error(y, yhat), "rho": correlation(yhat, y)}


class Algebraic:
    """Algebraic evaluation of candidates (paper section 2, Eq. 6-7): the default
    :class:`~msam_torch.run.evaluators.Evaluator`, registered as ``algebraic``."""

    simulates = False
    evaluate = staticmethod(evaluate)
    step = staticmethod(step)

    @staticmethod
    def starting_measures(data, theta, theta_fixed) -> dict:
        return starting_measures(data, theta, theta_fixed)


class Trainer:
    def __init__(self, options: StepOptions = StepOptions(), round_robin_steps: int = 15,
                 refinement_steps: int = 70, chunk_size: int = 4096, evaluator: Evaluator = Algebraic,
                 diagnostics: bool = False):
        self.options = options
        self.round_robin_steps = round_robin_steps
        self.refinement_steps = refinement_steps
        self.chunk_size = chunk_size
        self.evaluator = evaluator
        self.diagnostics = diagnostics
        self.callbacks: dict[str, list[Callable]] = defaultdict(list)
        self.stop_requested = False  # set by a callback (a time limit): every loop ends, keeping its best state

    def add_callback(self, event: str, fn: Callable) -> None:
        self.callbacks[event].append(fn)

    def trigger(self, event: str, **payload) -> None:
        for fn in self.callbacks[event]:
            fn(self, **payload)

    def fit(self, data: EquationData, theta: torch.Tensor, theta_fixed: torch.Tensor,
            start: torch.Tensor | None = None, choices: torch.Tensor | None = None) -> Fit:
        """Run Algorithm 1. ``theta`` (T, Q) and ``theta_fixed`` (T, P) are the nominal values;
        ``start`` (Q,) the starting exponents (default 0); ``choices`` (C, Q) the candidates
        (default: every combination of the adjustment functions)."""
        t, q = theta.shape
        if choices is None:
            choices = enumerate_choices(data.log_f.shape[-1], q, device=data.y.device)
        start = torch.zeros(q, dtype=data.y.dtype, device=data.y.device) if start is None else start
        ranking_fitness, ranking, diverged = self.round_robin(data, theta, theta_fixed, start, choices)
        winner = ranking_fitness.argmax(1)
        self.trigger("round_robin_end", choices=choices, ranking_fitness=ranking_fitness, winner=winner)

        trials = torch.arange(t, device=winner.device)
        winning_choice = choices[winner].unsqueeze(1)  # (T, 1, Q)
        winning_state = _map_state(lambda x: x[trials, winner].unsqueeze(1), ranking)
        _, refined, _ = self._adapt(data, winning_choice, winning_state, self.refinement_steps, "refinement_step", 0,
                                    initial_best=ranking_fitness[trials, winner].unsqueeze(1))
        final = self.evaluator.evaluate(data.select(winning_choice), replace(refined, diverged=torch.zeros_like(refined.diverged)),
                                        self.options)
        fit = Fit(
            choices=choices, ranking_fitness=ranking_fitness, ranking_gamma=ranking.gamma, winner=winner,
            gamma=refined.gamma[:, 0], theta=final.theta[:, 0], theta_fixed=final.theta_fixed[:, 0],
            start=self.evaluator.starting_measures(data, theta, theta_fixed),
            adapted=measures(data.y, final.yhat[:, 0]), diverged=diverged,
            initial=None if refined.initial is None else refined.initial[:, 0],
        )
        self.trigger("refinement_end", fit=fit)
        return fit

    def round_robin(self, data, theta, theta_fixed, start, choices, offset: int = 0):
        """Stage 1 over ``choices`` in chunks: each candidate's best fitness (T, C), its best
        :class:`State` (T, C, ...) and whether it diverged (T, C). ``offset`` numbers the
        candidates in events."""
        t, q = theta.shape[0], choices.shape[1]
        best, diverged = [], []
        for first in range(0, choices.shape[0], self.chunk_size):
            chunk = choices[first: first + self.chunk_size]
            shape = (t, chunk.shape[0])
            state = State(start.expand(shape + start.shape[-1:]).clone(), theta.unsqueeze(1).expand(shape + (q,)),
                          theta_fixed.unsqueeze(1).expand(shape + theta_fixed.shape[-1:]),
                          torch.zeros(shape, dtype=torch.bool, device=theta.device))
            result = self._adapt(data, chunk, state, self.round_robin_steps, "round_robin_step", offset + first)
            best.append(result[:2]), diverged.append(result[2])
        ranking = _map_state(lambda *xs: torch.cat(xs, 1), *[b[1] for b in best])
        return torch.cat([b[0] for b in best], 1), ranking, torch.cat(diverged, 1)

    def _adapt(self, data, choices, state, steps, event, offset, initial_best=None):
        """Iterate a batch of candidates from ``state``; return each one's best fitness, its
        state, and which diverged."""
        selection = data.select(choices)
        evaluator = self.evaluator
        current = evaluator.evaluate(selection, state, self.options)
        state = replace(state, theta=current.theta, theta_fixed=current.theta_fixed, initial=current.initial)
        if initial_best is None:
            best_fitness = torch.full(state.diverged.shape, -torch.inf, dtype=state.gamma.dtype, device=state.gamma.device)
        else:
            best_fitness = initial_best
        best = state
        for iteration in range(steps):
            if self.stop_requested:
                break
            result = evaluator.step(selection, state, current, self.options, conditions=self.diagnostics)
            if _unmoved(state, result.state):  # the step is a function of the state: every later one repeats this
                break
            state = result.state
            current = evaluator.evaluate(selection, state, self.options)
            improved = current.fitness > best_fitness
            best_fitness = torch.where(improved, current.fitness, best_fitness)
            best = _map_state(lambda new, old: torch.where(improved.view(improved.shape + (1,) * (new.dim() - 2)), new, old),
                              replace(state, theta=current.theta, theta_fixed=current.theta_fixed, initial=current.initial), best)
            self.trigger(event, iteration=iteration, offset=offset, choices=choices, result=result, evaluation=current)
        return best_fitness, best, state.diverged


def _unmoved(old: State, new: State) -> bool:
    """Whether a step left every candidate where it was (no step size raised a fitness, nor did any
    candidate diverge): exponents, theta and initial states all equal."""
    pairs = [(old.gamma, new.gamma), (old.theta, new.theta), (old.theta_fixed, new.theta_fixed),
             (old.diverged, new.diverged)] + ([(old.initial, new.initial)] if old.initial is not None else [])
    return all(torch.equal(a, b) for a, b in pairs)


def _map_state(fn, *states: State) -> State:
    """Apply ``fn`` field by field to states of the same layout (``initial`` may be None)."""
    fields = {}
    for name in ("gamma", "theta", "theta_fixed", "diverged", "initial"):
        values = [getattr(s, name) for s in states]
        fields[name] = None if values[0] is None else fn(*values)
    return State(**fields)


def starting_measures(data: EquationData, theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
    """Measures of the unadjusted starting model with nominal theta (docs/design.md 2.5)."""
    yhat = data.unadjusted @ theta.unsqueeze(-1)
    yhat = yhat.squeeze(-1) + (data.fixed_components @ theta_fixed.unsqueeze(-1)).squeeze(-1)
    return measures(data.y, yhat)
