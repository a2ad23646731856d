"""How sure a selection is: the null-verdict rule for a significant effect, the bootstrap trials'
outcomes and how often the named effect wins them, the margin to the best other name and whether
rows no fit saw tell the winner from every hypothesis with another name.

Null-verdict rule (docs/design.md section 3): an effect is reported only if its held-out RMSE beats the
theta-refitted starting model by at least ``relative`` (5 %) and by ``absolute`` (0.2 %) of the
held-out target's RMS.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from msam_torch.diagnosis.compare.verdict import Verdict
from msam_torch.diagnosis.options import DiagnoseOptions

RESAMPLES = 1000  # block-bootstrap resamples of out-of-sample rows (:func:`told_apart`)


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


@dataclass(frozen=True)
class Evidence:
    """Out-of-sample errors of every hypothesis: on the held-out rows (C, M') and on the fitted
    training rows, each predicted by a fit of the other blocks (C, M,
    :func:`~msam_torch.diagnosis.effects.hypotheses.crossed_errors`), with the number of independent rows of each."""

    held_out: torch.Tensor
    crossed: torch.Tensor
    blocks: tuple[int, int]

    def extended(self, more: "Evidence") -> "Evidence":
        """This evidence and ``more`` hypotheses' on the same rows."""
        return Evidence(torch.cat([self.held_out, more.held_out]), torch.cat([self.crossed, more.crossed]),
                        self.blocks)


@dataclass(frozen=True)
class Pinned:
    """The hypotheses held at catalogue entries' exponents: their :class:`Evidence`, entry names,
    fitted equations and the hypotheses they were pinned from."""

    evidence: Evidence
    names: list[str]
    equations: list[str]
    hypotheses: list[int]  # the hypothesis each was pinned from


def resamples(blocks: int, generator: torch.Generator) -> torch.Tensor:
    """:data:`RESAMPLES` draws of ``blocks`` block indices, each drawn with replacement (R, blocks)."""
    return torch.randint(0, blocks, (RESAMPLES, blocks), generator=generator)


def told_apart(errors: torch.Tensor, best: int, rival: int, draws: torch.Tensor, margin: float = 0.0) -> float:
    """The share of block-bootstrap resamples of out-of-sample rows on which hypothesis ``rival``
    predicts within ``margin`` of ``best`` (its root sum of squared ``errors`` (C, M) at most
    ``1 / (1 - margin)`` times the best's; a non-finite error counts for the rival): a one-sided
    p-value that ``best`` is not better by the margin. ``draws`` (:func:`resamples`) pick contiguous
    blocks of rows; their number is the number of independent rows (rows within a test function's
    reach share their errors, :meth:`~msam_torch.diagnosis.stages.rows.WeakForm.apart`), and the p-value is at least
    2^-blocks, the chance that ``best`` wins every block when neither is better."""
    blocks = draws.shape[-1]
    square = lambda c: torch.stack([part.square().sum() for part in torch.tensor_split(errors[c], blocks)])
    draws = draws.to(errors.device)
    within = ~(square(best)[draws].sum(-1) < (1 - margin) ** 2 * square(rival)[draws].sum(-1))
    return max(float(within.double().mean()), 0.5**blocks)


def apart(evidence: Evidence, best: int, others: list[int], relative: float,
          generator: torch.Generator) -> tuple[int | None, dict]:
    """The hypothesis of ``others`` hardest to tell ``best`` from, and the p-values: each is told
    apart by the held-out rows (:func:`told_apart`) or by the crossed training rows at the null
    rule's margin ``relative`` (rows of the training excitation share the estimator's bias with
    every fit on them, so a preference there must also be relevant in size); its p-value is the
    lesser of the two, and the rival's is the greatest (0 without others). Every hypothesis is
    compared on the same resamples, so that a p-value does not depend on the others tested."""
    found, rival = {"apart_p": 0.0, "apart_p_held_out": 0.0, "apart_p_training": 0.0}, None
    draws = [resamples(blocks, generator) for blocks in evidence.blocks]
    for c in others:
        held = told_apart(evidence.held_out, best, c, draws[0])
        crossed = told_apart(evidence.crossed, best, c, draws[1], relative)
        if rival is None or min(held, crossed) > found["apart_p"]:
            rival = c
            found = {"apart_p": min(held, crossed), "apart_p_held_out": held, "apart_p_training": crossed}
    return rival, found


def summary(rmse: torch.Tensor, names: list[str], best: int, is_significant: bool, outcome: str,
            trial_outcomes: list[str], is_effect: torch.Tensor, evidence: Evidence, relative: float,
            generator: torch.Generator, pinned: Pinned | None = None) -> dict:
    """The report's ``confidence``: ``margin`` (held-out RMSE of the best effect hypothesis with
    another name, relative to the chosen one's), ``runner_up``; ``rival``, of the effect hypotheses
    (``is_effect``) with another name (an uncatalogued power law too) and the hypotheses ``pinned``
    at another entry's catalogue exponent (their evidence and names), the one hardest to tell
    apart on out-of-sample ``evidence`` (:func:`apart`: ``apart_p``, ``apart_p_held_out``,
    ``apart_p_training``; 0 without a rival), and ``rival_equation``, the rival's fitted equation
    where it is a pinned one (None otherwise: the ranking lists the free fits'); ``win_frequency``
    of ``outcome`` over the bootstrap trials (NaN without trials) and the ``outcomes`` counted."""
    frequency = win_frequency(trial_outcomes, outcome) if trial_outcomes else float("nan")
    ranked = [int(c) for c in torch.argsort(rmse) if torch.isfinite(rmse[c])]
    runner = next((c for c in ranked if names[c] != names[best] and bool(is_effect[c])), None) if is_significant else best
    reference = rmse[best] if is_significant else rmse[0]
    margin = float((rmse[runner] - reference) / reference) if runner is not None and reference > 0 else float("inf")
    others, labels, equations = [], names, [None] * len(names)
    if is_significant:
        others = [c for c in ranked if names[c] != names[best] and c != 0 and bool(is_effect[c])]
        if pinned is not None:
            evidence = evidence.extended(pinned.evidence)
            labels = names + [f"{name} at its catalogue exponent" for name in pinned.names]
            equations = equations + pinned.equations
            others += [rmse.shape[0] + k for k, name in enumerate(pinned.names) if name != names[best]]
    rival, found = apart(evidence, best, others, relative, generator)
    return {"margin": margin, "runner_up": names[runner] if runner is not None and is_significant else None,
            "rival": None if rival is None else labels[rival], **found,
            "rival_equation": None if rival is None else equations[rival],
            "win_frequency": frequency, "bootstrap_trials": len(trial_outcomes),
            "outcomes": {o: trial_outcomes.count(o) for o in sorted(set(trial_outcomes))}}


def at_catalogue_exponent(pinned: Pinned | None, form: set[int], name: str) -> str | None:
    """The fitted equation of the best hypothesis's form (the hypotheses ``form``: its starts) held
    at the exponent of the entry ``name``, theta re-fitted: the named effect's coefficient in the
    catalogue's own law (Coulomb friction's force, not the coefficient of ``|v|^-0.93``); None
    where no such pin was fitted."""
    if pinned is None:
        return None
    return next((eq for h, n, eq in zip(pinned.hypotheses, pinned.names, pinned.equations) if h in form and n == name),
                None)
