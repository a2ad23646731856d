"""Theta re-estimation for fixed exponents (design notes section 3; the paper's Tables 5-6).

For fixed exponents the model of Eq. 9 is linear in theta, so theta follows from one linear least
squares solve: before adaptation on the starting model (the paper tunes the starting model first
on real data) and after it (the "parameter-tuned adapted model"). ``hold_fixed`` keeps the fixed
components (e.g. the input term ``u/m``) at their nominal theta and solves only the adjustable
ones. The relative distance of the nominal theta from the tuned one is the parametric error that
the data reveal. Batched over trials T like :mod:`msam_torch.engine.trainer`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from msam_torch.engine.candidates import EquationData, columns
from msam_torch.engine.step import lstsq
from msam_torch.engine.trainer import measures


@dataclass(frozen=True)
class Tuned:
    """Least-squares theta (T, Q) and (T, P) and the measures of the tuned model (dict of (T,))."""

    theta: torch.Tensor
    theta_fixed: torch.Tensor
    measures: dict


def solve(y: torch.Tensor, cols: torch.Tensor, fixed: torch.Tensor, theta_fixed: torch.Tensor,
          hold_fixed: bool) -> Tuned:
    """Theta minimising ``||y - cols theta - fixed theta_fixed||`` (theta_fixed given if held).

    y (T, N), cols (T, N, Q), fixed (T, N, P), theta_fixed (T, P)."""
    fixed = fixed.expand(cols.shape[:-1] + fixed.shape[-1:])
    if hold_fixed:
        residual = y - (fixed @ theta_fixed.unsqueeze(-1)).squeeze(-1)
        theta = lstsq(cols, residual)
    else:
        solution = lstsq(torch.cat([cols, fixed], -1), y.expand(cols.shape[:-1]))
        theta, theta_fixed = solution[..., : cols.shape[-1]], solution[..., cols.shape[-1]:]
    yhat = (cols @ theta.unsqueeze(-1)).squeeze(-1) + (fixed @ theta_fixed.unsqueeze(-1)).squeeze(-1)
    return Tuned(theta, theta_fixed.expand(theta.shape[:-1] + theta_fixed.shape[-1:]), measures(y, yhat))


def tune_start(data: EquationData, theta_fixed: torch.Tensor, hold_fixed: bool = False) -> Tuned:
    """The parameter-tuned starting model (no adjustment, Eq. 2)."""
    return solve(data.y, data.unadjusted, data.fixed_components, theta_fixed, hold_fixed)


def tune_adapted(data: EquationData, choice: torch.Tensor, gamma: torch.Tensor, theta_fixed: torch.Tensor,
                 hold_fixed: bool = False) -> Tuned:
    """The parameter-tuned adapted model: ``choice`` (T, Q) functions at exponents ``gamma`` (T, Q).

    Theta is in the units of :class:`EquationData`'s (possibly normalised) adjustment functions."""
    cols = columns(data.select(choice.unsqueeze(1)), gamma.unsqueeze(1))[:, 0]
    return solve(data.y, cols, data.fixed_components, theta_fixed, hold_fixed)


def measure_model(data: EquationData, choice: torch.Tensor | None, gamma: torch.Tensor | None,
                  theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
    """Measures of a model on ``data`` (e.g. held-out samples): the starting model when ``choice``
    is None, else ``choice`` (T, Q) at ``gamma`` (T, Q); theta (T, Q), theta_fixed (T, P)."""
    if choice is None:
        cols = data.unadjusted
    else:
        cols = columns(data.select(choice.unsqueeze(1)), gamma.unsqueeze(1))[:, 0]
    fixed = data.fixed_components.expand(cols.shape[:-1] + data.fixed_components.shape[-1:])
    yhat = (cols @ theta.unsqueeze(-1)).squeeze(-1) + (fixed @ theta_fixed.unsqueeze(-1)).squeeze(-1)
    return measures(data.y, yhat)


def relative_error(nominal: torch.Tensor, tuned: torch.Tensor) -> torch.Tensor:
    """``|nominal - tuned| / |tuned|`` per component (inf where the tuned theta is 0)."""
    difference = (nominal - tuned).abs()
    return torch.where(tuned != 0, difference / tuned.abs().clamp_min(torch.finfo(tuned.dtype).tiny),
                       torch.where(difference == 0, torch.zeros_like(difference), torch.full_like(difference, torch.inf)))
