"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it
shrinks (``msam diagnose``; docs/design.md section 3).

``diagnose(config, data=None, validation=None) -> GapReport``; ``GapReport.save(out)`` writes
``gap_report.json`` and ``report.md`` with PNG plots; ``GapReport.verdict_kind`` is a
:class:`Verdict`.
"""
from msam_torch.diagnosis.catalogue.entries import NOT_CATALOGUED, entries
from msam_torch.diagnosis.compare.verdict import Verdict
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.report.gap_report import EquationGap, GapReport
from msam_torch.diagnosis.stages.pipeline import diagnose

__all__ = ["diagnose", "DiagnoseOptions", "GapReport", "EquationGap", "Verdict", "entries", "NOT_CATALOGUED"]
