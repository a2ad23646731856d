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
from dataclasses import dataclass
from typing import Callable, Mapping, Optional

import torch
from torch import nn

from .spec import Equation

FLOOR = 1e-12  # smallest |f| (after normalisation) before powers and logarithms
MAX_LOG = 300.0  # largest exponent argument: keeps f^gamma finite in float64 and products of a few


def enumerate_choices(n_functions: int, n_adjustable: int, device=None) -> torch.Tensor:
    """Every assignment of one of F functions to each of Q components: (F**Q, Q) indices."""
    rows = list(itertools.product(range(n_functions), repeat=n_adjustable))
    return torch.tensor(rows, dtype=torch.long, device=device)


@dataclass(frozen=True)
class EquationData:
    """One state equation's signals on the samples, batched over trials.

    ``log_f`` and ``sign_f`` hold ``log max(|f|/scale, FLOOR)`` and the sign factor of every
    adjustment function; ``scale`` is 1 or the function's RMS (``normalize='rms'``).
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
    project: Optional[Callable[[torch.Tensor], torch.Tensor]] = None

    @classmethod
    def build(cls, equation: Equation, signals: Mapping[str, torch.Tensor], normalize: str = "none") -> "EquationData":
        """Evaluate terms and functions on ``signals`` (each (N,) or (T, N))."""
        values = {k: v if v.dim() == 2 else v.unsqueeze(0) for k, v in signals.items()}
        y = values[equation.target]
        shape = y.shape

        def evaluate(expression):
            value = expression(values)
            if not torch.is_tensor(value):
                value = torch.tensor(value, dtype=y.dtype, device=y.device)
            return value.to(y.dtype).expand(shape)

        terms = [evaluate(c.term) for c in equation.components]
        stack = lambda items: torch.stack(items, -1) if items else y.new_zeros(shape + (0,))
        f = stack([evaluate(a) for a in equation.adjustments])
        magnitude = torch.tensor([a.is_magnitude for a in equation.adjustments], device=y.device)
        if normalize == "rms":
            scale = torch.sqrt((f * f).mean(-2)).clamp_min(torch.finfo(f.dtype).tiny)
        else:
            scale = torch.ones(f.shape[:1] + f.shape[-1:], dtype=f.dtype, device=f.device)
        log_f = torch.log((f.abs() / scale.unsqueeze(-2)).clamp_min(FLOOR))
        sign_f = torch.where(magnitude, torch.ones_like(f), torch.sign(f))
        return cls(
            y=y,
            components=stack([terms[i] for i in equation.adjustable]),
            fixed_components=stack([terms[i] for i in equation.fixed]),
            log_f=log_f,
            sign_f=sign_f,
            scale=scale,
        )

    def select(self, choice: torch.Tensor) -> "Selection":
        """Gather each candidate's functions; ``choice`` is (C, Q) or per trial (T, C, Q)."""
        t, n, _ = self.log_f.shape
        index = choice.expand((t,) + choice.shape[-2:]) if choice.dim() == 2 else choice
        c, q = index.shape[-2:]
        gather = lambda values: values.unsqueeze(1).expand(t, c, n, -1).gather(-1, index.unsqueeze(2).expand(t, c, n, q))
        signed = self.components.unsqueeze(1) * gather(self.sign_f)
        return Selection(self.y.unsqueeze(1), signed, gather(self.log_f), self.fixed_components.unsqueeze(1),
                         self.project)


@dataclass(frozen=True)
class Selection:
    """The data of a batch of candidates, ready for :func:`columns` (T, C, N, Q)."""

    y: torch.Tensor  # (T, 1, N)
    signed_components: torch.Tensor  # (T, C, N, Q): M_i * sign factor of its f
    log_f: torch.Tensor  # (T, C, N, Q)
    fixed_components: torch.Tensor  # (T, 1, N, P)
    project: Optional[Callable[[torch.Tensor], torch.Tensor]] = None  # see EquationData


def power(log_f: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """``|f|^gamma = exp(gamma log|f|)``, clamped below overflow."""
    return torch.exp((gamma * log_f).clamp(max=MAX_LOG))


def columns(selection: Selection, gamma: torch.Tensor) -> torch.Tensor:
    """Adjusted components ``M_i f_i^gamma_i`` (Eq. 9) for gamma of shape (T, C, Q)."""
    cols = selection.signed_components * power(selection.log_f, gamma.unsqueeze(-2))
    return cols if selection.project is None else selection.project(cols)


def predict(selection: Selection, cols: torch.Tensor, theta: torch.Tensor, theta_fixed: torch.Tensor) -> torch.Tensor:
    """``yhat = sum_i theta_i M_i f_i^gamma_i + sum_j theta_j M_j`` (Eq. 6, 9): (T, C, N)."""
    yhat = (cols * theta.unsqueeze(-2)).sum(-1)
    if theta_fixed.shape[-1]:
        yhat = yhat + (selection.fixed_components * theta_fixed.unsqueeze(-2)).sum(-1)
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
