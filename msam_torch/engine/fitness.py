"""Fitness (Eq. 19) and the error measures reported beside it.

All functions reduce over the last (sample) axis and broadcast over leading batch axes.
"""
from __future__ import annotations

import torch


def correlation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Pearson correlation rho(a, b) over the last axis; 0 where either side is constant."""
    a = a - a.mean(-1, keepdim=True)
    b = b - b.mean(-1, keepdim=True)
    rho = torch.linalg.vecdot(a, b) / torch.sqrt(torch.linalg.vecdot(a, a) * torch.linalg.vecdot(b, b))
    return rho.nan_to_num_(0.0, 0.0, 0.0)  # 0/0 (a constant side) and a vanished denominator


def sum_abs_error(y: torch.Tensor, yhat: torch.Tensor) -> torch.Tensor:
    """``sum_k |eps(t_k)|`` with ``eps = y - yhat`` (Eq. 4)."""
    return (y - yhat).abs().sum(-1)


def fitness(y: torch.Tensor, yhat: torch.Tensor) -> torch.Tensor:
    """Eq. 19: ``F = rho(yhat, y) / sum|eps|``; -inf where yhat is not finite."""
    return scores(y, yhat)[0]


def scores(y: torch.Tensor, yhat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Fitness (Eq. 19), ``sum|eps|`` and rho together, each computed once."""
    rho, error = correlation(yhat, y), sum_abs_error(y, yhat)
    value = rho / error
    return torch.where(torch.isfinite(value), value, torch.full_like(value, -torch.inf)), error, rho


def nrmse(y: torch.Tensor, yhat: torch.Tensor) -> torch.Tensor:
    """Root-mean-square error over the standard deviation of ``y``."""
    rmse = torch.sqrt(((y - yhat) ** 2).mean(-1))
    return rmse / y.std(-1)
