"""The rules of one MSAM step that the config names: the step size ``mu`` of Eq. 18
(:class:`StepSizeRule`, one of :data:`STEP_SIZES`); how theta is treated is the config's
:class:`~msam_torch.config.schema.ThetaRule`.

``adaptation.step_size`` names a rule or, from Python, is one (any object with ``name``, ``mu`` and
``settled``). The config schema imports this module, so it imports no torch at load: the rules work
on the tensors they are given.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, ClassVar, Protocol, runtime_checkable

from msam_torch.config.registry import Registry

if TYPE_CHECKING:
    from torch import Tensor

LINE_SEARCH_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125)


@runtime_checkable
class StepSizeRule(Protocol):
    """mu of every candidate (T, C) for the step ``delta`` of Eq. 17."""

    name: str

    def mu(self, fitness: Tensor, predicted: Tensor, eps: Tensor, trial_fitness: Callable,
           settled: Tensor | None = None) -> Tensor:
        """``fitness`` (T, C) now; ``predicted`` the first-order change ``Phi dGamma`` (..., N) of
        Eq. 11; ``eps`` the error (..., N); ``trial_fitness(mu, among)`` the fitness (T, C) of the
        candidates moved by ``mu * delta``, needed only where ``among`` (T, C) holds; ``settled``
        (T, C): candidates whose previous search found no step (see :meth:`settled`)."""
        ...

    def settled(self, mu: Tensor) -> Tensor | None:
        """Candidates (T, C) whose next step would again find no ``mu`` (None: the rule has none)."""
        ...


@dataclass(frozen=True)
class Eq20:
    """Eq. 20: ``mu = corr(eps, Phi dGamma)``, the paper's rule."""

    name: ClassVar[str] = "eq20"

    def mu(self, fitness, predicted, eps, trial_fitness, settled=None):
        from msam_torch.engine.fitness import correlation  # torch, loaded with the engine rather than the config schema

        return correlation(eps, predicted)

    def settled(self, mu):
        return None


@dataclass(frozen=True)
class One:
    """``mu = 1``: the full Gauss-Newton step."""

    name: ClassVar[str] = "one"

    def mu(self, fitness, predicted, eps, trial_fitness, settled=None):
        return fitness.new_ones(fitness.shape)

    def settled(self, mu):
        return None


@dataclass(frozen=True)
class LineSearch:
    """Backtracking: the largest mu in ``steps`` that raises the fitness (0 if none). It stops as
    soon as every candidate has its mu, and skips settled candidates: the step being a function of
    the state alone, a search that found nothing would find nothing again."""

    name: ClassVar[str] = "line_search"
    steps: tuple[float, ...] = LINE_SEARCH_STEPS

    def mu(self, fitness, predicted, eps, trial_fitness, settled=None):
        mu = fitness.new_zeros(fitness.shape)
        open_ = fitness.new_ones(fitness.shape, dtype=bool) if settled is None else ~settled
        for value in self.steps:
            if not bool(open_.any()):
                break
            better = trial_fitness(value, open_) > fitness
            mu = mu.masked_fill(open_ & better, value)
            open_ = open_ & ~better
        return mu

    def settled(self, mu):
        return mu == 0


STEP_SIZES: Registry[StepSizeRule] = Registry("adaptation.step_size", StepSizeRule, "step-size rule")
for _rule in (Eq20, One, LineSearch):
    STEP_SIZES.register(_rule.name, _rule)
