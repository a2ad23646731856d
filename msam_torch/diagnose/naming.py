"""Catalogue names of fitted hypotheses (:mod:`.catalogue`), with exponents snapped into an
entry's interval when that keeps most of the improvement (noise biases exponents, design.md
section 3)."""
from __future__ import annotations

import torch

from ..candidates import EquationData, columns
from ..spec import Equation
from ..step import solve_theta
from . import catalogue
from .hypotheses import Fitted, Hypothesis, predict_rows, slot
from .verdict import Verdict
from .weak import WeakForm


def snapped_names(equation: Equation, hypotheses: list[Hypothesis], weak: WeakForm, fit_data: EquationData,
                  choices: torch.Tensor, fitted: Fitted, rmse: torch.Tensor, nominal: torch.Tensor,
                  keep: float) -> tuple[list[list[str]], torch.Tensor]:
    """Catalogue names of every trial and hypothesis (T, C) and the exponents they name.

    Each effect exponent is moved to the nearest catalogued value for its signal roles, theta is
    re-solved on ``fit_data`` (variable projection), and the name is given when the snapped model
    keeps ``keep`` of the free exponent's held-out improvement (``rmse`` (T, C)) over the
    re-fitted start; else 'power law, no catalogued effect'. The re-fitted start is named
    'no significant gap'."""
    gamma = fitted.gamma.clone()
    for c, h in enumerate(hypotheses):
        entries = [] if h.kind == "retuned" else catalogue.entries_for(equation, h.component, h.function)
        if entries:
            g = gamma[:, c, slot(equation, h)]
            options = torch.stack([g.clamp(e.low, e.high) for e in entries], -1)
            nearest = (options - g.unsqueeze(-1)).abs().argmin(-1, keepdim=True)
            gamma[:, c, slot(equation, h)] = options.gather(-1, nearest).squeeze(-1)
    selection = fit_data.select(choices)
    theta, theta_fixed = solve_theta(selection, columns(selection, gamma))
    moved = Fitted(gamma, theta, theta_fixed, fitted.fitness, fitted.invalid)
    yhat = predict_rows(weak.val_data, choices, moved)[..., weak.val_rows]
    snapped_rmse = torch.sqrt(((yhat - weak.y_val) ** 2).mean(-1))
    kept = (rmse[:, :1] - snapped_rmse) >= keep * (rmse[:, :1] - rmse)
    names = []
    for k in range(gamma.shape[0]):
        row = []
        for c, h in enumerate(hypotheses):
            if h.kind == "retuned":
                row.append(Verdict.NO_GAP.text())
                continue
            s = slot(equation, h)
            named = catalogue.name_effect(equation, h.component, h.function, float(gamma[k, c, s]),
                                          float(theta[k, c, s]), float(nominal[h.component]))
            row.append(named if bool(kept[k, c]) else catalogue.NOT_CATALOGUED)
        names.append(row)
    return names, gamma


def named_exponent(h: Hypothesis, equation: Equation, name: str, gamma: torch.Tensor) -> float | None:
    """The exponent a catalogue name refers to (the fitted one moved into the entry's interval)."""
    if h.kind == "retuned" or name in (Verdict.NO_GAP.text(), catalogue.NOT_CATALOGUED):
        return None
    return float(gamma[slot(equation, h)])
