"""Parameter and exponent intervals of the reported model: each term of the winning hypothesis's
equation with its coefficient (theta in the data's units, Eq. 6) and exponent, and their 90 %
bootstrap percentile intervals over the trials that re-fitted it (:mod:`msam_torch.diagnosis.effects.bootstrap`)."""
from __future__ import annotations

import torch

from msam_torch.diagnosis.compare.measures import interval
from msam_torch.diagnosis.effects.bootstrap import Bootstrap
from msam_torch.diagnosis.effects.hypotheses import Fitted
from msam_torch.model.notation import format_component
from msam_torch.model.spec import Equation


def term_intervals(extended: Equation, equation: Equation, choices: torch.Tensor, original: Fitted,
                   boot: Bootstrap | None, c: int, scale: torch.Tensor) -> list[dict]:
    """Per term of hypothesis ``c`` (switched-off copies left out, as in its equation text):
    ``term``, ``theta`` and ``exponent`` (None for an unadjusted term) of the original fit, and
    ``theta_interval``/``exponent_interval`` ([low, high]; None without bootstrap trials)."""
    n_f = len(equation.adjustments)
    slots = {i: k for k, i in enumerate(extended.adjustable)}
    fixed = {i: k for k, i in enumerate(extended.fixed)}
    valid = None
    if boot is not None:
        valid = ~boot.fitted.invalid[:, c] & torch.isfinite(boot.rmse[:, c])
    # theta in the data's units per trial (row 0: the original fit): the normalisation |f/s|^gamma folded back
    fits = [original] + ([] if boot is None else [boot.fitted])
    gamma = torch.cat([f.gamma[:, c] for f in fits])
    theta = torch.cat([f.theta[:, c] for f in fits]) * scale[choices[c]] ** (-gamma)
    theta_fixed = torch.cat([f.theta_fixed[:, c] for f in fits])
    terms = []
    for i in range(len(extended.components)):
        if i in fixed:
            values, exponents, text = theta_fixed[:, fixed[i]], None, format_component(extended, i, None, None)
        else:
            k, f = slots[i], int(choices[c, slots[i]])
            if f == n_f + 1:  # a switched-off copy
                continue
            adjusted = f < n_f
            values = theta[:, k]
            exponents = gamma[:, k] if adjusted else None
            text = format_component(extended, i, f if adjusted else None, float(gamma[0, k]) if adjusted else None)
        trials = lambda v: None if valid is None or int(valid.sum()) < 2 else interval(v[1:][valid])
        terms.append({"term": text, "theta": float(values[0]), "theta_interval": trials(values),
                      "exponent": None if exponents is None else float(exponents[0]),
                      "exponent_interval": None if exponents is None else trials(exponents)})
    return terms
