"""Candidate models (Eq. 8-9): enumeration, one candidate as an ``nn.Module``, the batched family.

A candidate picks one adjustment function ``f`` from the set F for every adjustable component and
adds an exponent: ``M_i -> M_i * f_i^gamma_i``, with ``|f|^gamma`` for magnitude functions
(``abs(...)``) and ``sign(f)|f|^gamma`` for signed ones. ``|f|`` is floored before its logarithm,
so ``0**gamma`` and ``log 0`` stay finite; powers are clamped below overflow.

Shapes: ``T`` trials, ``C`` candidates, ``N`` samples, ``Q`` adjustable components, ``P`` fixed
components, ``F`` adjustment functions.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field, fields, replace
from typing import Callable, Mapping, Optional

import numpy as np
import torch
from torch import nn

from msam_torch.model.spec import Equation

FLOOR = 1e-12  # smallest |f| (after normalisation) before powers and logarithms
MAX_LOG = 300.0  # largest exponent argument: keeps f^gamma finite in float64 and products of a few


def enumerate_choices(n_functions: int, n_adjustable: int, device=None) -> torch.Tensor:
    """Every assignment of one of F functions to each of Q components: (F**Q, Q) indices."""
    rows = list(itertools.product(range(n_functions), repeat=n_adjustable))
    return torch.tensor(rows, dtype=torch.long, device=device)


def equation_choices(equation: Equation, device=None) -> torch.Tensor:
    """Every candidate of ``equation`` (C, Q): one function of each adjustable component's own
    set (``Equation.allowed``), in the order of :func:`enumerate_choices` when all are allowed."""
    rows = list(itertools.product(*(equation.allowed(i) for i in equation.adjustable)))
    return torch.tensor(rows, dtype=torch.long, device=device)


@dataclass(frozen=True)
class EquationData:
    """One state equation's signals on the samples, batched over trials.

    ``log_f`` and ``sign_f`` hold ``log max(|f|/scale, FLOOR)`` and the sign factor of every
    adjustment function; ``scale`` is 1 or the function's RMS (``normalize='rms'``). With
    ``normalize='rms'`` every adjustable component ``M_i`` is divided by its RMS too
    (``component_scale``), so every column the step sees (Eq. 15-17) is dimensionless and a theta
    in the data's units is ``theta_normalised * scale^-gamma / component_scale``.
    ``project`` (optional) is a linear map along the sample axis applied to the adjusted columns
    (..., N, Q) -> (..., M, Q), e.g. integration against test functions (weak form); ``y`` and
    ``fixed_components`` are then given in the projected space (M rows).
    """

    y: torch.Tensor  # (T, N) target derivative
    components: torch.Tensor  # (T, N, Q) adjustable M_i
    fixed_components: torch.Tensor  # (T, N, P) fixed M_i
    log_f: torch.Tensor  # (T, N, F)
    sign_f: torch.Tensor  # (T, N, F)
    scale: torch.Tensor  # (T, F)
    component_scale: torch.Tensor | None = None  # (T, Q); None means 1
    project: Optional[Callable[[torch.Tensor], torch.Tensor]] = None

    @property
    def theta_scale(self) -> torch.Tensor:
        """Factor (T, Q) from a component's theta in data units to normalised units."""
        if self.component_scale is None:
            return torch.ones_like(self.components[:, 0])
        return self.component_scale

    @property
    def unadjusted(self) -> torch.Tensor:
        """The adjustable components without adjustment (T, N, Q), mapped by ``project`` when set."""
        return self.components if self.project is None else self.project(self.components.unsqueeze(1)).squeeze(1)

    def expand_trials(self, trials: int) -> "EquationData":
        """The same data viewed ``trials`` times along the leading axis (no copy)."""
        grow = lambda v: v.expand(trials, *v.shape[1:]) if torch.is_tensor(v) else v
        return replace(self, **{f.name: grow(getattr(self, f.name)) for f in fields(self)})

    @classmethod
    def build(cls, equation: Equation, signals: Mapping[str, torch.Tensor], normalize: str = "none") -> "EquationData":
        """Evaluate terms and functions on ``signals`` (each (N,) or (T, N)).

        ``normalize``: ``'none'``; ``'rms'`` divides every adjustment function and every adjustable
        component by its RMS; ``'functions'`` divides the adjustment functions only (components and
        theta stay in the data's units)."""
        values = {k: v if v.dim() == 2 else v.unsqueeze(0) for k, v in signals.items()}
        shape = torch.Size(np.broadcast_shapes(*(v.shape for v in values.values())))  # torch's imports sympy
        y = values[equation.target].expand(shape)

        def evaluate(expression):
            value = expression(values)
            if not torch.is_tensor(value):
                value = torch.tensor(value, dtype=y.dtype, device=y.device)
            return value.to(y.dtype).expand(shape)

        terms = [evaluate(c.term) for c in equation.components]
        stack = lambda items: torch.stack(items, -1) if items else y.new_zeros(shape + (0,))
        f = stack([evaluate(a) for a in equation.adjustments])
        magnitude = torch.tensor([a.is_magnitude for a in equation.adjustments], device=y.device)
        components = stack([terms[i] for i in equation.adjustable])
        rms = lambda v: torch.sqrt((v * v).mean(-2)).clamp_min(torch.finfo(v.dtype).tiny)
        ones = lambda v: torch.ones(v.shape[:1] + v.shape[-1:], dtype=f.dtype, device=f.device)
        scale = rms(f) if normalize in ("rms", "functions") else ones(f)
        component_scale = rms(components) if normalize == "rms" else ones(components)
        components = components / component_scale.unsqueeze(-2)
        log_f = torch.log((f.abs() / scale.unsqueeze(-2)).clamp_min(FLOOR))
        sign_f = torch.where(magnitude, torch.ones_like(f), torch.sign(f))
        return cls(
            y=y,
            components=components,
            fixed_components=stack([terms[i] for i in equation.fixed]),
            log_f=log_f,
            sign_f=sign_f,
            scale=scale,
            component_scale=component_scale,
        )

    def select(self, choice: torch.Tensor) -> "Selection":
        """Gather each candidate's functions; ``choice`` is (C, Q) or per trial (T, C, Q).

        The (T, C, N, Q) tensors are stored sample-axis last in memory (views of (T, C, Q, N)), so
        the elementwise passes, the sums over samples and the Gram products of a step run along
        contiguous memory; the values are the same in either layout."""
        t, n, f = self.log_f.shape
        index = choice.expand((t,) + choice.shape[-2:]) if choice.dim() == 2 else choice
        c, q = index.shape[-2:]
        rows = index.unsqueeze(-1).expand(t, c, q, n)
        gather = lambda values: values.mT.unsqueeze(1).expand(t, c, f, n).gather(2, rows)  # (T, C, Q, N)
        signed = self.components.mT.contiguous().unsqueeze(1) * gather(self.sign_f)
        return Selection(self.y.unsqueeze(1), signed.mT, gather(self.log_f).mT, self.fixed_components.unsqueeze(1),
                         self.project)


@dataclass(frozen=True)
class Selection:
    """The data of a batch of candidates, ready for :func:`columns` (T, C, N, Q)."""

    y: torch.Tensor  # (T, 1, N)
    signed_components: torch.Tensor  # (T, C, N, Q): M_i * sign factor of its f
    log_f: torch.Tensor  # (T, C, N, Q)
    fixed_components: torch.Tensor  # (T, 1, N, P)
    project: Optional[Callable[[torch.Tensor], torch.Tensor]] = None  # see EquationData
    _factors: dict = field(default_factory=dict, repr=False, compare=False)
    _levels: list = field(default_factory=list, repr=False, compare=False)

    def perturbation_factor(self, dgamma: float) -> torch.Tensor:
        """``|f|^dgamma - 1`` (cached): column i at ``gamma_i + dgamma`` minus at ``gamma_i`` is
        the column times this factor (Eq. 15-16), so a step needs no second power."""
        if dgamma not in self._factors:
            self._factors[dgamma] = torch.expm1(dgamma * self.log_f)
        return self._factors[dgamma]

    def levels(self) -> tuple[tuple[torch.Tensor, torch.Tensor], torch.Tensor, torch.Tensor]:
        """(cached) ``varying`` (candidate and column indices): the columns whose ``log|f|`` changes
        along the samples in some trial; ``level`` (T, C, Q): ``log|f|`` at the first sample; ``base`` (T, C, M, Q): the
        components projected. A column whose ``|f|`` is constant (``1``, ``0``, a fixed level) is
        ``M_i |f|^gamma = |f|^gamma M_i``, and the projection is linear, so its projected column is
        ``|f|^gamma`` times its projected component: one projection for every step."""
        if not self._levels:
            level = self.log_f[..., 0, :]
            varying = (self.log_f != level.unsqueeze(-2)).any(-2).any(0).nonzero(as_tuple=True)
            self._levels.extend((varying, level, self.project(self.signed_components)))
        return tuple(self._levels)

    def take(self, trials: torch.Tensor, candidates: torch.Tensor) -> "Selection":
        """Candidate ``candidates[k]`` of trial ``trials[k]`` for each k, as K trials of one
        candidate (sample axis kept last in memory). Not for projected selections, whose row
        weights may be per trial."""
        assert self.project is None, "a projected selection is evaluated whole"
        t = self.log_f.shape[0]
        pick = lambda values: values.mT[trials, candidates].mT.unsqueeze(1)
        rows = lambda values: values.expand((t,) + values.shape[1:])[trials]
        return Selection(rows(self.y), pick(self.signed_components), pick(self.log_f), rows(self.fixed_components))


def power(log_f: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """``|f|^gamma = exp(gamma log|f|)``, clamped below overflow."""
    return torch.exp((gamma * log_f).clamp(max=MAX_LOG))


def columns(selection: Selection, gamma: torch.Tensor) -> torch.Tensor:
    """Adjusted components ``M_i f_i^gamma_i`` (Eq. 9) for gamma of shape (..., T, C, Q),
    mapped by ``selection.project`` when one is set.

    The same values as ``signed_components * power(log_f, gamma)``, computed in one buffer; a
    projected selection evaluates and projects only its varying columns (:meth:`Selection.levels`)."""
    if selection.project is not None:
        return _projected_columns(selection, gamma)
    value = (gamma.unsqueeze(-1) * selection.log_f.mT).mT  # broadcast along the stored sample axis
    return value.clamp_(max=MAX_LOG).exp_().mul_(selection.signed_components)


def _projected_columns(selection: Selection, gamma: torch.Tensor) -> torch.Tensor:
    (c, q), level, base = selection.levels()
    cols = base * power(level, gamma).unsqueeze(-2)  # (..., T, C, M, Q)
    if c.numel():  # (..., T, K, N) of the K varying columns, projected as (..., T, 1, N, K)
        value = power(selection.log_f.mT[:, c, q], gamma[..., c, q].unsqueeze(-1)) * selection.signed_components.mT[:, c, q]
        cols.mT[..., c, q, :] = selection.project(value.mT.unsqueeze(-3)).squeeze(-3).mT
    return cols


def predict(selection: Selection, cols: torch.Tensor, theta: torch.Tensor, theta_fixed: torch.Tensor) -> torch.Tensor:
    """``yhat = sum_i theta_i M_i f_i^gamma_i + sum_j theta_j M_j`` (Eq. 6, 9): (T, C, N)."""
    yhat = (theta.unsqueeze(-2) @ cols.mT).squeeze(-2)  # row form: cols are stored sample-axis last
    if theta_fixed.shape[-1]:
        yhat = yhat + torch.einsum("...np,...cp->...cn", selection.fixed_components.squeeze(-3), theta_fixed)
    return yhat


class Candidate(nn.Module):
    """One candidate model (Eq. 9): exponents are the parameter, theta and the choice buffers.

    ``forward(data)`` returns yhat of shape (T, N). Stack several with
    :func:`torch.func.stack_module_state` and evaluate them with ``vmap`` + ``functional_call``
    (:func:`evaluate_stacked`); the trainer uses the equivalent batched functions above.
    """

    def __init__(self, choice: torch.Tensor, theta: torch.Tensor, theta_fixed: torch.Tensor, start: torch.Tensor | None = None):
        super().__init__()
        q = choice.shape[-1]
        start = torch.zeros(q, dtype=theta.dtype, device=theta.device) if start is None else start
        self.gamma = nn.Parameter(start.clone())
        self.register_buffer("choice", choice)
        self.register_buffer("theta", theta)
        self.register_buffer("theta_fixed", theta_fixed)

    def columns(self, data: EquationData) -> torch.Tensor:
        """Adjusted components (T, N, Q)."""
        log_f = torch.index_select(data.log_f, -1, self.choice)
        sign_f = torch.index_select(data.sign_f, -1, self.choice)
        return data.components * sign_f * power(log_f, self.gamma)

    def forward(self, data: EquationData) -> torch.Tensor:
        return self.columns(data) @ self.theta + data.fixed_components @ self.theta_fixed


def evaluate_stacked(candidates: list[Candidate], data: EquationData) -> torch.Tensor:
    """yhat of every candidate in one vmapped call: (C, T, N)."""
    from torch.func import functional_call, stack_module_state, vmap

    params, buffers = stack_module_state(candidates)
    base = candidates[0]
    return vmap(lambda p, b: functional_call(base, (p, b), (data,)))(params, buffers)
