"""The verdict of a diagnosis: one equation's, from the null rule, the bootstrap, the residual
structure left and (for "no significant gap") the residual checks; the report's, from its
equations' and the free runs' checks (docs/design.md section 3): a verdict is given only when the
free run of the model it rests on (the adapted model for an explained gap, else the theta
re-fitted start) does not diverge and is no worse than the nominal model's on held-out data;
otherwise it is inconclusive, with the reasons and what to try."""
from __future__ import annotations

from dataclasses import replace
from enum import Enum
from typing import Sequence

from msam_torch.diagnosis.catalogue.entries import NOT_CATALOGUED
from msam_torch.diagnosis.options import AGREEMENT, DiagnoseOptions


class Verdict(str, Enum):
    """What a diagnosis concludes; :meth:`text` renders it for people (``verdict`` in the report),
    the value is the machine form (``verdict_kind`` in gap_report.json)."""

    EXPLAINED = "explained"
    NO_GAP = "no_gap"
    NOT_EXPLAINED = "not_explained"
    INCONCLUSIVE = "inconclusive"  # a check failed: the reasons say which and what to try

    def text(self, effect: str | None = None) -> str:
        if self is Verdict.EXPLAINED:
            return f"gap explained by {effect}"
        return _TEXT[self]


_TEXT = {Verdict.NO_GAP: "no significant gap", Verdict.NOT_EXPLAINED: "gap not explained by a catalogued effect",
         Verdict.INCONCLUSIVE: "inconclusive"}
NO_WORSE = 0.01  # the re-fitted start's held-out free-run NRMSE may exceed the nominal one's by this share
NO_INFORMATION = 1.0  # a free run whose NRMSE reaches this is no closer to the record than its mean
TRY = {"estimation": "try another --half-width or a held-out record from another excitation",
       "diverged": "try --solver dopri5 or a smaller --solver-step; a model that diverges on its own is not a fit",
       "residual": "the starting model misses something the candidates do not express: add candidate adjustments "
                   "or components, or try another --half-width",
       "simulated residual": "the starting model misses something the candidates do not express: add candidate "
                             "adjustments or components",
       "adaptation diverged": "a damped step (adaptation.damping, e.g. 0.1) may keep the adaptation by simulation "
                              "stable",
       "length": "a longer held-out record gives the residual checks the independent rows they need",
       "apart": "a record that spans a wider range of the signals the two read, or another excitation, may tell "
                "them apart",
       "loose": "a longer or less noisy record, or an excitation that spans a wider range of the signal the law "
                "reads, holds its exponent closer"}


def equation_verdict(significant: bool, effect: str, confidence: dict, structure_left: float,
                     checks: dict, options: DiagnoseOptions, loose: str | None = None,
                     located: str | None = None) -> tuple[Verdict, list[str]]:
    """One equation and its reasons; ``effect``: the name of the best effect hypothesis. A
    significant effect (null rule) is explained when it has a catalogue name, predicts
    out-of-sample rows better than every effect hypothesis with another name beyond chance
    (:func:`.confidence.apart`: ``confidence["apart_p"]`` at most ``options.apart_level``), wins
    at least ``options.min_win_frequency`` of the bootstrap trials (NaN without trials: not
    checked) and leaves at most ``options.max_structure_left`` of the residual structure. When it
    is not told apart from its rival and either of the two has a name (a catalogued effect, or
    one held at its catalogue exponent), the data do not tell which explains the gap: inconclusive,
    naming both; "not explained" is left for a gap that only uncatalogued laws fit best. No
    significant effect is "no significant gap" only when the re-fitted start's residual passes
    ``checks`` (:func:`~msam_torch.diagnosis.stages.structure.residual_checks`), else inconclusive. Either verdict is
    inconclusive where a law whose exponent is held too loosely to be an effect predicts the
    held-out rows better by the null rule's margin (``loose``: what it is and what it beats): the
    data show the gap's law but do not fix it. No significant effect where the starting model
    fails in a region of the record (``located``: where, how much, the fixed components that read
    it) is a gap no hypothesis expresses: not explained, never "no significant gap"; unless the
    re-fitted start's held-out weak-form residual is within the null rule's absolute margin
    (``checks["negligible"]``): the one-step rows then split the error of the derivative estimates."""
    if loose is not None:
        return Verdict.INCONCLUSIVE, [f"{loose}: these data do not fix the law of the gap", TRY["loose"]]
    if not significant:
        missed = located is not None and not checks.get("negligible")
        return (Verdict.NOT_EXPLAINED, [located]) if missed else no_gap_verdict(checks)
    named = effect != NOT_CATALOGUED
    rival = confidence.get("rival")
    if confidence["apart_p"] > options.apart_level and (named or rival not in (None, NOT_CATALOGUED)):
        return Verdict.INCONCLUSIVE, [f"the best fit, {effect}, is not told apart from {rival} on out-of-sample "
                                      f"rows (p = {confidence['apart_p']:.2g}): these data do not tell which "
                                      "explains the gap", TRY["apart"]]
    if named and not confidence["win_frequency"] < options.min_win_frequency \
            and structure_left <= options.max_structure_left:
        return Verdict.EXPLAINED, []
    return Verdict.NOT_EXPLAINED, []


def no_gap_verdict(checks: dict, hint: str = TRY["residual"]) -> tuple[Verdict, list[str]]:
    """No significant effect: "no significant gap" when the re-fitted start's residual passes its
    ``checks``, else inconclusive with the checks it failed and ``hint``, what to try. Where the
    held-out rows were too few to test for structure (``unchecked``), the evidence is a residual
    above the noise estimate alone, which does not say the candidates miss something: the hint is
    then the longer record the checks need."""
    if checks["failed"]:
        return Verdict.INCONCLUSIVE, [*checks["failed"], TRY["length"] if checks.get("unchecked") else hint]
    return Verdict.NO_GAP, []


def free_run_reasons(free_run: dict, kind: Verdict) -> list[str]:
    """Why the free runs do not support a verdict of ``kind`` (held-out data, else training): the
    model the verdict rests on diverged, or is worse than the nominal model by more than
    :data:`NO_WORSE` and the resolution the free runs are checked to (:data:`~msam_torch.diagnosis.options.AGREEMENT`)
    (where the nominal model diverged: is no closer to the record than its mean,
    :data:`NO_INFORMATION`), or the runs it rests on did not converge (its model's, and the nominal
    model's where that decides the comparison, :func:`_needed`). An explained gap rests on the
    adapted model, any other verdict on the theta re-fitted start: a re-fit of a structure that
    misses an effect compensates for it on the training excitation and may simulate other data
    worse than the nominal theta, and a nominal model that diverges is a finding; neither undoes an
    explanation whose adapted model beats the nominal one."""
    if not free_run:
        return []
    label = "held_out" if "held_out" in free_run else "train"
    entry = free_run[label]
    diverged, nrmse = entry["diverged"], entry["nrmse"]
    model = rests_on(kind)
    reasons = [f"the {_MODEL[model]} model's free run on {label} data diverged"] if model in diverged else []
    unsettled = [m for m in entry["solver"]["unconverged"]
                 if m == model or (m == "start" and _needed(nrmse, model))]
    if unsettled:
        reasons.append(f"the free runs of the {' and '.join(_MODEL[m] for m in unsettled)} model"
                       f"{'s' if len(unsettled) > 1 else ''} did not converge when the {entry['solver']['method']} "
                       f"step was halved to {entry['solver']['step']:.3g}")
    if reasons:
        return reasons + [TRY["diverged"]]
    if "start" in diverged and nrmse[model] >= NO_INFORMATION:
        return [f"the nominal model's free run on {label} data diverged and the {_MODEL[model]} model's does not "
                f"follow the record (NRMSE {nrmse[model]:.3g}, no closer than its mean)", TRY["estimation"]]
    if "start" not in diverged and nrmse[model] > (1 + NO_WORSE) * nrmse["start"] + AGREEMENT:
        return [f"the {_MODEL[model]} model's free run on {label} data is worse than the nominal model's "
                f"(NRMSE {nrmse[model]:.3g} vs {nrmse['start']:.3g}): {_WORSE[model]}", TRY["estimation"]]
    return []


def rests_on(kind: Verdict) -> str:
    """The model a verdict of ``kind`` rests on: the adapted one for an explained gap, else the
    theta re-fitted start (:func:`free_run_reasons`)."""
    return "adapted" if kind is Verdict.EXPLAINED else "retuned"


def _needed(nrmse: dict, model: str) -> bool:
    """Whether the nominal model's free-run NRMSE decides the comparison with ``model``'s: not when
    it diverged, nor when it is no closer to the record than its mean (:data:`NO_INFORMATION`)
    while ``model``'s is (a run that far off says only that, and its exact value does not matter)."""
    start, own = nrmse["start"], nrmse[model]
    return start is not None and not (own is not None and start >= NO_INFORMATION > own)


_MODEL = {"start": "starting", "retuned": "theta re-fitted", "adapted": "adapted"}
_WORSE = {"retuned": "the estimation is off", "adapted": "the effect does not carry over to other data"}


def overall(gaps: Sequence, significant: bool, name_targets: bool,
            free_run: dict | None = None) -> tuple[Verdict, str, list[str]]:
    """The report's verdict from its equations' (:class:`~msam_torch.diagnosis.report.gap_report.EquationGap`) and the free runs:
    inconclusive when :func:`free_run_reasons` finds any; else every explained equation's
    (``in <target>`` when ``name_targets``), followed by the equations left inconclusive; else
    inconclusive when an equation is; else not explained when ``significant`` or an equation is
    not explained (a located gap); else no gap. Returns the kind, its text and the reasons (those of
    the equations inconclusive or not explained)."""
    explained = [g for g in gaps if g.verdict_kind is Verdict.EXPLAINED]
    undecided = [g for g in gaps if g.verdict_kind is Verdict.INCONCLUSIVE]
    missed = significant or any(g.verdict_kind is Verdict.NOT_EXPLAINED for g in gaps)
    kind = (Verdict.EXPLAINED if explained else Verdict.INCONCLUSIVE if undecided
            else Verdict.NOT_EXPLAINED if missed else Verdict.NO_GAP)
    reasons = free_run_reasons(free_run or {}, kind)
    if reasons:
        return Verdict.INCONCLUSIVE, Verdict.INCONCLUSIVE.text(), reasons
    open_reasons = [f"{g.target}: {r}" for g in gaps for r in g.checks.get("reasons", [])
                    if g.verdict_kind in (Verdict.INCONCLUSIVE, Verdict.NOT_EXPLAINED)]
    if explained:
        parts = [f"{g.verdict} in {g.target}" if name_targets else g.verdict for g in explained]
        return kind, "; ".join(parts + [f"{g.target} inconclusive" for g in undecided]), open_reasons
    return kind, kind.text(), open_reasons


def demoted(gaps: Sequence, kind: Verdict, reasons: list[str]) -> tuple:
    """The equations as the report states them: when the free runs leave the report inconclusive
    although an equation explained its gap (:func:`overall`), that equation is inconclusive too,
    with the report's ``reasons`` added to its own, so that no equation reads "explained" under an
    inconclusive report."""
    if kind is not Verdict.INCONCLUSIVE:
        return tuple(gaps)
    return tuple(replace(g, verdict_kind=Verdict.INCONCLUSIVE,
                         checks={**g.checks, "reasons": [*g.checks.get("reasons", []), *reasons]})
                 if g.verdict_kind is Verdict.EXPLAINED else g for g in gaps)
