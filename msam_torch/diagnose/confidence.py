"""How sure a selection is: the null-verdict rule for a significant effect, the bootstrap trials'
outcomes and how often the named effect wins them, the margin to the best other name and whether
the held-out data tell the two apart.

Null-verdict rule (docs/design.md section 3): an effect is reported only if its held-out RMSE beats the
theta-refitted starting model by at least ``relative`` (5 %) and by ``absolute`` (0.2 %) of the
held-out target's RMS.
"""
from __future__ import annotations

import torch

from .options import DiagnoseOptions
from .verdict import Verdict

RESAMPLES = 1000  # block-bootstrap resamples of the held-out rows (:func:`told_apart`)


def significant(rmse: torch.Tensor, retuned: torch.Tensor, target_rms: float, relative: float = 0.05,
                absolute: float = 0.002) -> torch.Tensor:
    """The null-verdict rule, elementwise."""
    return (rmse <= (1 - relative) * retuned) & (retuned - rmse >= absolute * target_rms)


def win_frequency(outcomes: list[str], name: str) -> float:
    return sum(o == name for o in outcomes) / max(len(outcomes), 1)


def best_effect(rmse: torch.Tensor, is_effect: torch.Tensor) -> torch.Tensor:
    """Index of the effect hypothesis (not the re-fitted start) with the least held-out RMSE, (...,)."""
    return torch.where(is_effect, rmse, torch.full_like(rmse, torch.inf)).argmin(-1)


def outcomes(names: list[list[str]], rmse: torch.Tensor, is_effect: torch.Tensor, target_rms: float,
             options: DiagnoseOptions) -> list[str]:
    """Each bootstrap trial's outcome: the name of its best effect hypothesis when that passes the
    null rule, else 'no significant gap'; ``names`` (T, C), ``rmse`` (T, C) held out."""
    found = []
    for k, b in enumerate(best_effect(rmse, is_effect).tolist()):
        ok = bool(significant(rmse[k, b], rmse[k, 0], target_rms, options.relative, options.absolute))
        found.append(names[k][b] if ok else Verdict.NO_GAP.text())
    return found


def told_apart(errors: torch.Tensor, best: int, rival: int, blocks: int, generator: torch.Generator) -> float:
    """The share of block-bootstrap resamples of the held-out rows on which hypothesis ``rival``
    predicts at least as well as ``best`` (sum of squared ``errors`` (C, M)): a one-sided p-value
    that ``best`` is no better. :data:`RESAMPLES` draws of ``blocks`` contiguous blocks of rows,
    each drawn with replacement; ``blocks`` is the number of independent held-out rows (rows within
    a test function's reach share their errors, :meth:`.weak.WeakForm.independent_rows`), and the
    p-value is at least 2^-blocks, the chance that ``best`` wins every block when neither is better."""
    square = lambda c: torch.stack([part.square().sum() for part in torch.tensor_split(errors[c], blocks)])
    draws = torch.randint(0, blocks, (RESAMPLES, blocks), generator=generator).to(errors.device)
    share = float((square(rival)[draws].sum(-1) <= square(best)[draws].sum(-1)).double().mean())
    return max(share, 0.5**blocks)


def summary(rmse: torch.Tensor, names: list[str], best: int, is_significant: bool, outcome: str,
            trial_outcomes: list[str], is_effect: torch.Tensor, errors: torch.Tensor, blocks: int,
            generator: torch.Generator, pinned: tuple[torch.Tensor, list[str]] | None = None) -> dict:
    """The report's ``confidence``: ``margin`` (held-out RMSE of the best hypothesis with another
    name, relative to the chosen one's), ``runner_up``; ``rival``, the best effect hypothesis
    (``is_effect``) with another name (an uncatalogued power law too) or, better still on the
    held-out rows, a hypothesis ``pinned`` at another entry's catalogue exponent (its errors
    (P, M) and names), and ``apart_p`` (:func:`told_apart` on the held-out ``errors`` (C, M); 0
    without a rival); ``win_frequency`` of ``outcome`` over the bootstrap trials (NaN without
    trials) and the ``outcomes`` counted."""
    frequency = win_frequency(trial_outcomes, outcome) if trial_outcomes else float("nan")
    ranked = [int(c) for c in torch.argsort(rmse) if torch.isfinite(rmse[c])]
    runner = next((c for c in ranked if names[c] != names[best] and c != 0), None) if is_significant else best
    reference = rmse[best] if is_significant else rmse[0]
    margin = float((rmse[runner] - reference) / reference) if runner is not None and reference > 0 else float("inf")
    rival = next((c for c in ranked if names[c] != names[best] and c != 0 and bool(is_effect[c])), None) \
        if is_significant else None
    labels = names
    if is_significant and pinned is not None:
        errors = torch.cat([errors, pinned[0]])
        labels = names + [f"{name} at its catalogue exponent" for name in pinned[1]]
        others = [rmse.shape[0] + k for k, name in enumerate(pinned[1]) if name != names[best]]
        rival = min(([] if rival is None else [rival]) + others, key=lambda c: float(errors[c].square().mean()),
                    default=None)
    return {"margin": margin, "runner_up": names[runner] if runner is not None and is_significant else None,
            "rival": None if rival is None else labels[rival],
            "apart_p": 0.0 if rival is None else told_apart(errors, best, rival, blocks, generator),
            "win_frequency": frequency, "bootstrap_trials": len(trial_outcomes),
            "outcomes": {o: trial_outcomes.count(o) for o in sorted(set(trial_outcomes))}}
