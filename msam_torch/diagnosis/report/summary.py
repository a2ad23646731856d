"""The report's plain-language summary, read before its numbers: per equation, what the starting
model misses, where, how much better the adapted model predicts held-out data and how sure the
choice is; the fitted exponent ``gamma`` and the total exponent the catalogue compares told apart."""
from __future__ import annotations

import math

from msam_torch.diagnosis.compare.verdict import Verdict


def summary(report) -> list[str]:
    """One paragraph per equation of ``report`` (a :class:`~msam_torch.diagnosis.report.gap_report.GapReport`)."""
    return [paragraph(g) for g in report.equations]


def paragraph(g) -> str:
    """The plain-language summary of one :class:`~msam_torch.diagnosis.report.gap_report.EquationGap`."""
    if not g.significant:
        if g.verdict_kind is Verdict.NO_GAP:
            return (f"{g.target}: nothing is missing that the data show. The starting model, its parameters re-fitted, "
                    "predicts the held-out data as well as any candidate effect, and its residual passes the "
                    "whiteness checks.")
        return f"{g.target}: {g.verdict}; no candidate effect predicts the held-out data better.{_where(g)}"
    return " ".join(part for part in (_what(g), _form(g), _where(g).strip(), _better(g), _sure(g)) if part)


def _what(g) -> str:
    if g.verdict_kind is Verdict.EXPLAINED:
        description = (g.naming or {}).get("description")
        return f"{g.target}: the starting model misses {g.effect}" + (f" ({description})." if description else ".")
    if g.verdict_kind is Verdict.NOT_EXPLAINED:
        return f"{g.target}: the starting model misses something that no catalogued effect names."
    return f"{g.target}: the data do not settle what the starting model misses; {g.effect} fits best (the reasons say why)."


def _form(g) -> str:
    """The best hypothesis, and what its fitted ``gamma`` and its total exponent each mean."""
    if g.exponent is None:
        return f"The best fit is {g.hypothesis}."
    text = f"The best fit is {g.hypothesis} with gamma = {g.exponent:.3f}"
    naming = g.naming or {}
    if naming.get("total_exponent") is None or not naming.get("on"):
        return text + "."
    term = "the adjusted term" if g.kind == "multiplicative" else "the added term"
    on, total, half = naming["on"], naming["total_exponent"], naming["half_width"]
    catalogue = "" if g.catalogue_exponent is None else f"; {g.effect}: {g.catalogue_exponent}"
    return (f"{text}: {term} varies as |{on}|^{total:.2f} ± {half:.2f} (gamma plus the power of {on} in the term "
            f"it multiplies: the total exponent the catalogue compares{catalogue}).")


def _where(g) -> str:
    where = g.where or {}
    if not where.get("flagged_fraction") or not where.get("regions"):
        return ""
    region = where["regions"][0]
    return f" The starting model fails most where {region['rule']} ({100 * region['share']:.0f} % of the record)."


def _better(g) -> str:
    relative = (g.improvement or {}).get("relative")
    if relative is None or not math.isfinite(relative):
        return ""
    return (f"On held-out data the adapted model's error (RMSE of {g.target}) is {100 * relative:.0f} % lower than "
            "that of the starting model with its parameters re-fitted.")


def _sure(g) -> str:
    c = g.confidence
    if not c.get("bootstrap_trials"):
        return ""
    text = (f"How sure: it is the best fit in {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']} "
            "bootstrap re-fits (time blocks and noise re-drawn)")
    runner, rival = c.get("runner_up"), c.get("rival")
    if runner is not None and math.isfinite(c.get("margin") or math.inf):
        text += f"; the next best explanation ({runner}) has a {100 * c['margin']:.0f} % larger held-out error"
    if rival is not None and c.get("apart_p_held_out") is not None:
        who = " and" if rival == runner else f"; the closest rival ({rival})"
        text += f"{who} predicts as well in {100 * c['apart_p_held_out']:.0f} % of held-out resamples"
    return text + "."
