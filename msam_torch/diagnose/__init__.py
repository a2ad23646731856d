"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it
shrinks (``msam diagnose``; design.md section 3).

``diagnose(config, data=None, validate=None) -> GapReport``; ``GapReport.save(out)`` writes
``gap_report.json`` and ``report.md`` with PNG plots.
"""
from .catalogue import CATALOGUE, NOT_CATALOGUED
from .core import EXPLAINED, NO_GAP, NOT_EXPLAINED, DiagnoseOptions, diagnose
from .report import EquationGap, GapReport

__all__ = ["diagnose", "DiagnoseOptions", "GapReport", "EquationGap", "CATALOGUE", "NOT_CATALOGUED", "NO_GAP",
           "NOT_EXPLAINED", "EXPLAINED"]
