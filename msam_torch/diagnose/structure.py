"""Residual structure a hypothesis leaves: how much of the re-fitted start's held-out weak-form
residual a k-nearest-neighbour regression on the equation's signals predicts, before and after
the effect (a verdict check: an effect that leaves most of the structure does not explain the gap)."""
from __future__ import annotations

import torch

from ..spec import Equation
from .hypotheses import Fitted, predict_rows
from .weak import TestFunctions, WeakForm

NEIGHBOURS = 10


def _features(equation: Equation, signals: dict, tests: TestFunctions):
    names = sorted(n for n in equation.signals - {equation.target, "t"} if n in signals)
    return names, torch.stack([tests.average(signals[n]) for n in names], -1)


def structure_left(equation: Equation, weak: WeakForm, choices: torch.Tensor, original: Fitted, best: int) -> float:
    """Share of the re-fitted start's residual structure (what a k-nearest-neighbour regression on
    the equation's signals predicts on held-out rows) that hypothesis ``best`` leaves."""
    _, x_fit = _features(equation, weak.signals, weak.tests)
    _, x_val = _features(equation, weak.val_signals, weak.val_tests)
    x_fit, x_val = x_fit[weak.fit_rows], x_val[weak.val_rows]
    spread = x_fit.std(0).clamp_min(torch.finfo(x_fit.dtype).tiny)
    distance = torch.cdist(x_val / spread, x_fit / spread)
    k = min(NEIGHBOURS, x_fit.shape[0])
    neighbours = distance.topk(k, largest=False).indices
    fit_pred = predict_rows(weak.data, choices, original)[0]  # rows of the weighted fit: weights are 0/1
    val_pred = predict_rows(weak.val_data, choices, original)[0]
    explained = []
    for c in (0, best):
        r_fit = (weak.data.y[0] - fit_pred[c])[weak.fit_rows]
        r_val = (weak.val_data.y[0] - val_pred[c])[weak.val_rows]
        guess = r_fit[neighbours].mean(-1)
        explained.append(float(((r_val**2).mean() - ((r_val - guess) ** 2).mean()).clamp_min(0)))
    return explained[1] / explained[0] if explained[0] > 0 else 0.0
