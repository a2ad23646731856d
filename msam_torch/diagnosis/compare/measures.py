"""How far the gap shrinks: one-step (algebraic) and free-run (simulated) error measures of the
starting, theta-retuned and adapted models, and the part of the gap each step closes.

Measures per model: NRMSE (RMSE over the standard deviation of the measurement), ``sum|eps|``
(Eq. 4) and rho (Pearson correlation, Eq. 19). A diverged simulation scores NRMSE = inf.
"""
from __future__ import annotations

import torch

from msam_torch.engine.fitness import correlation, nrmse, sum_abs_error

MODELS = ("start", "retuned", "adapted")


def error_measures(y: torch.Tensor, yhat: torch.Tensor) -> dict:
    """NRMSE, sum|eps| and rho of ``yhat`` (B, N) against ``y`` (N,): lists of B floats."""
    finite = torch.isfinite(yhat).all(-1)
    safe = torch.where(finite.unsqueeze(-1), yhat, torch.zeros_like(yhat))
    inf = torch.full(finite.shape, torch.inf, dtype=y.dtype)
    return {
        "nrmse": torch.where(finite, nrmse(y, safe), inf).tolist(),
        "sum_abs_error": torch.where(finite, sum_abs_error(y, safe), inf).tolist(),
        "rho": torch.where(finite, correlation(safe, y), torch.zeros_like(inf)).tolist(),
    }


def by_model(values: dict, names=MODELS) -> dict:
    """``{'nrmse': [a, b, c], ...}`` -> ``{'start': {'nrmse': a, ...}, ...}`` for the first models."""
    return {m: {k: v[i] for k, v in values.items()} for i, m in enumerate(names)}


def closure(start: torch.Tensor, retuned: torch.Tensor, adapted: torch.Tensor) -> dict:
    """Shares of the starting error closed by retuning theta and by the effect (fractions of start),
    and the share of the re-fitted start's error the effect closes (``effect_on_retuned``: where the
    start is far off, the effect's part of the starting error is small whatever it does)."""
    nan = lambda v: torch.where(torch.isfinite(v) & (v > 0), v, torch.full_like(v, torch.nan))
    scale, base = nan(start), nan(retuned)
    on_retuned = (base - torch.where(torch.isfinite(adapted), adapted, base)) / base  # a diverged effect closes nothing
    clean = lambda v: torch.where(torch.isfinite(v), v, scale)  # a diverged model closes nothing
    retuned, adapted = clean(retuned), clean(adapted)
    return {"retuning": (scale - retuned) / scale, "effect": (retuned - adapted) / scale, "effect_on_retuned": on_retuned}


def interval(samples: torch.Tensor, level: float = 0.9) -> list[float]:
    """Central bootstrap percentile interval (NaN samples ignored)."""
    samples = samples[torch.isfinite(samples)]
    if samples.numel() == 0:
        return [float("nan"), float("nan")]
    q = torch.tensor([(1 - level) / 2, (1 + level) / 2], dtype=samples.dtype, device=samples.device)
    return torch.quantile(samples, q).tolist()
