"""The verdict of a diagnosis: one equation's, from the null rule, the bootstrap and the residual
structure left; the report's, from its equations' (design.md section 3)."""
from __future__ import annotations

from enum import Enum
from typing import Sequence

from .options import DiagnoseOptions


class Verdict(str, Enum):
    """What a diagnosis concludes; :meth:`text` renders it for people (``verdict`` in the report),
    the value is the machine form (``verdict_kind`` in gap_report.json)."""

    EXPLAINED = "explained"
    NO_GAP = "no_gap"
    NOT_EXPLAINED = "not_explained"
    INCONCLUSIVE = "inconclusive"  # the data cannot tell (no stage decides this yet)

    def text(self, effect: str | None = None) -> str:
        if self is Verdict.EXPLAINED:
            return f"gap explained by {effect}"
        return _TEXT[self]


_TEXT = {Verdict.NO_GAP: "no significant gap", Verdict.NOT_EXPLAINED: "gap not explained by the candidate set",
         Verdict.INCONCLUSIVE: "inconclusive: the data cannot tell"}


def equation_verdict(significant: bool, named: bool, win_frequency: float, structure_left: float,
                     options: DiagnoseOptions) -> Verdict:
    """One equation: a significant effect (null rule) is explained when it has a catalogue name, wins
    at least ``options.min_win_frequency`` of the bootstrap trials (NaN without trials: not
    checked) and leaves at most ``options.max_structure_left`` of the residual structure."""
    if not significant:
        return Verdict.NO_GAP
    if named and not win_frequency < options.min_win_frequency and structure_left <= options.max_structure_left:
        return Verdict.EXPLAINED
    return Verdict.NOT_EXPLAINED


def overall(gaps: Sequence, significant: bool, name_targets: bool) -> tuple[Verdict, str]:
    """The report's verdict from its equations' (:class:`~.report.EquationGap`): every explained
    equation's (``in <target>`` when ``name_targets``), else not explained when ``significant``,
    else no gap."""
    explained = [g for g in gaps if g.verdict_kind is Verdict.EXPLAINED]
    if explained:
        return Verdict.EXPLAINED, "; ".join(f"{g.verdict} in {g.target}" if name_targets else g.verdict
                                            for g in explained)
    kind = Verdict.NOT_EXPLAINED if significant else Verdict.NO_GAP
    return kind, kind.text()
