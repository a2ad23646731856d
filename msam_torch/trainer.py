"""Algorithm 1: round robin over every candidate, then refinement of the winner.

The trainer owns the loop and fires named events; logging, progress bars and checkpoints are
callbacks (``trainer.add_callback(event, fn)``), each called as ``fn(trainer, **payload)``.
Events: ``round_robin_step``, ``round_robin_end``, ``refinement_step``, ``refinement_end``.
Candidates are processed in chunks of ``chunk_size`` so memory stays bounded; all trials of a
batch (leading axis T) run together.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from typing import Callable

import torch

from .candidates import EquationData, enumerate_choices, predict
from .fitness import correlation, fitness, sum_abs_error
from .step import State, StepOptions, evaluate, solve_theta, step


@dataclass(frozen=True)
class Fit:
    """Outcome of Algorithm 1 for one state equation, batched over T trials.

    ``choices`` (C, Q): the adjustment index of every adjustable component per candidate;
    ``ranking_fitness`` (T, C): each candidate's best fitness in the round robin;
    ``winner`` (T,); ``gamma`` (T, Q), ``theta`` (T, Q), ``theta_fixed`` (T, P): the adapted model;
    ``start`` / ``final``: dicts of (T,) tensors ``fitness``, ``sum_abs_error``, ``rho``;
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
    final: dict
    diverged: torch.Tensor


def measures(y: torch.Tensor, yhat: torch.Tensor) -> dict:
    return {"fitness": fitness(y, yhat), "sum_abs_error": sum_abs_error(y, yhat), "rho": correlation(yhat, y)}


class Trainer:
    def __init__(self, options: StepOptions = StepOptions(), round_robin_steps: int = 15,
                 refinement_steps: int = 70, chunk_size: int = 4096):
        self.options = options
        self.round_robin_steps = round_robin_steps
        self.refinement_steps = refinement_steps
        self.chunk_size = chunk_size
        self.callbacks: dict[str, list[Callable]] = defaultdict(list)

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
        t, _, q = data.components.shape
        if choices is None:
            choices = enumerate_choices(data.log_f.shape[-1], q, device=data.y.device)
        start = torch.zeros(q, dtype=data.y.dtype, device=data.y.device) if start is None else start
        ranking_fitness, ranking_gamma, diverged = self.round_robin(data, theta, theta_fixed, start, choices)
        winner = ranking_fitness.argmax(1)
        self.trigger("round_robin_end", choices=choices, ranking_fitness=ranking_fitness, winner=winner)

        trials = torch.arange(t, device=winner.device)
        winning_choice = choices[winner].unsqueeze(1)  # (T, 1, Q)
        refined_fitness, refined_gamma, _ = self._adapt(
            data, winning_choice, theta.unsqueeze(1), theta_fixed.unsqueeze(1), ranking_gamma[trials, winner].unsqueeze(1),
            self.refinement_steps, "refinement_step", 0, initial_best=ranking_fitness[trials, winner].unsqueeze(1))
        gamma = refined_gamma[:, 0]
        selection = data.select(winning_choice)
        final_state = State(gamma.unsqueeze(1), theta.unsqueeze(1), theta_fixed.unsqueeze(1),
                            torch.zeros(t, 1, dtype=torch.bool, device=gamma.device))
        final = evaluate(selection, final_state, self.options)
        fit = Fit(
            choices=choices, ranking_fitness=ranking_fitness, ranking_gamma=ranking_gamma, winner=winner, gamma=gamma,
            theta=final.theta[:, 0], theta_fixed=final.theta_fixed[:, 0],
            start=starting_measures(data, theta, theta_fixed),
            final=measures(data.y, final.yhat[:, 0]), diverged=diverged,
        )
        self.trigger("refinement_end", fit=fit)
        return fit

    def round_robin(self, data, theta, theta_fixed, start, choices, offset: int = 0):
        """Stage 1 over ``choices`` in chunks: each candidate's best fitness (T, C), its gamma
        (T, C, Q) and whether it diverged (T, C). ``offset`` numbers the candidates in events."""
        best_fitness, best_gamma, diverged = [], [], []
        for first in range(0, choices.shape[0], self.chunk_size):
            chunk = choices[first: first + self.chunk_size]
            result = self._adapt(data, chunk, theta.unsqueeze(1), theta_fixed.unsqueeze(1), start,
                                 self.round_robin_steps, "round_robin_step", offset + first)
            best_fitness.append(result[0]), best_gamma.append(result[1]), diverged.append(result[2])
        return torch.cat(best_fitness, 1), torch.cat(best_gamma, 1), torch.cat(diverged, 1)

    def _adapt(self, data, choices, theta, theta_fixed, start, steps, event, offset, initial_best=None):
        """Iterate a batch of candidates; return each one's best fitness, its gamma, diverged."""
        selection = data.select(choices)
        shape = selection.log_f.shape[:2]
        gamma = start.expand(shape + start.shape[-1:]).clone() if start.dim() < 3 else start.clone()
        state = State(gamma, theta.expand(shape + theta.shape[-1:]), theta_fixed.expand(shape + theta_fixed.shape[-1:]),
                      torch.zeros(shape, dtype=torch.bool, device=gamma.device))
        current = evaluate(selection, state, self.options)
        if initial_best is None:
            best_fitness, best_gamma = torch.full(shape, -torch.inf, dtype=gamma.dtype, device=gamma.device), gamma
        else:
            best_fitness, best_gamma = initial_best, gamma
        for iteration in range(steps):
            result = step(selection, state, current, self.options, conditions=bool(self.callbacks[event]))
            state = result.state
            current = evaluate(selection, state, self.options)
            improved = current.fitness > best_fitness
            best_fitness = torch.where(improved, current.fitness, best_fitness)
            best_gamma = torch.where(improved.unsqueeze(-1), state.gamma, best_gamma)
            self.trigger(event, iteration=iteration, offset=offset, choices=choices, result=result, evaluation=current)
        return best_fitness, best_gamma, state.diverged


def starting_measures(data: EquationData, theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
    """Measures of the unadjusted starting model with nominal theta (design.md 2.5)."""
    yhat = data.components @ theta.unsqueeze(-1)
    yhat = yhat.squeeze(-1) + (data.fixed_components @ theta_fixed.unsqueeze(-1)).squeeze(-1)
    return measures(data.y, yhat)
