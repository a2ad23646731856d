"""How sure a selection is: bootstrap trials over time blocks and measurement noise, run as one
batch on the leading trials axis, and the verdict rule for a significant effect.

Null-verdict rule (design.md section 3): an effect is reported only if its held-out RMSE beats the
theta-refitted starting model by at least ``relative`` (5 %) and by ``absolute`` (0.2 %) of the
held-out target's RMS.
"""
from __future__ import annotations

import torch


def block_weights(fit_rows: torch.Tensor, trials: int, blocks: int, generator: torch.Generator) -> torch.Tensor:
    """Moving-block bootstrap as weights (trials, M): ``blocks`` contiguous row blocks of the fitted
    rows are drawn with replacement; a row's weight counts how often its block was drawn."""
    m = fit_rows.shape[0]
    block_of = torch.div(torch.arange(m) * blocks, m, rounding_mode="floor")
    draws = torch.randint(0, blocks, (trials, blocks), generator=generator)
    counts = torch.zeros(trials, blocks, dtype=torch.float64).scatter_add_(1, draws, torch.ones(trials, blocks, dtype=torch.float64))
    return counts[:, block_of].to(fit_rows.device) * fit_rows.to(torch.float64)


def significant(rmse: torch.Tensor, retuned: torch.Tensor, target_rms: float, relative: float = 0.05,
                absolute: float = 0.002) -> torch.Tensor:
    """The null-verdict rule, elementwise."""
    return (rmse <= (1 - relative) * retuned) & (retuned - rmse >= absolute * target_rms)


def win_frequency(outcomes: list[str], name: str) -> float:
    return sum(o == name for o in outcomes) / max(len(outcomes), 1)
