"""The oracle fit of a zoo case's true structure: what the record can tell (issue 54).

The case's starting model with only the truth's component adjustable and only the truth's
function as its adjustment, in every equation the withheld effect enters (the other equations as
they are: the schema wants an adjustable component in each), diagnosed by the project's own fit and bootstrap
(:func:`msam_torch.diagnosis.diagnose`, no free run). The exponent is free. The record *pins* the
law when, in every such equation, the oracle's gap is significant and its exponent ``g`` with its
bootstrap half-width ``h`` stays within the catalogue's
:data:`~msam_torch.diagnosis.catalogue.entries.TOLERANCE` of the truth's even at the edge of its
interval beyond the catalogue's resolution: ``|g - truth| + (h - TOLERANCE) <= TOLERANCE`` (every
interval is at least the tolerance wide, :func:`~msam_torch.diagnosis.catalogue.naming.half_width`). A case whose record does not pin the law is not
*identifiable*: no diagnosis can be asked to name it.
"""
from __future__ import annotations

import copy

from msam_torch.diagnosis.catalogue.entries import TOLERANCE
from msam_torch.diagnosis.options import DiagnoseOptions

ORACLE_OPTIONS = DiagnoseOptions(free_run=False)


def oracle_config(config: dict, truth: dict) -> dict:
    """``config`` reduced to the truth's structure (a catalogued single effect's ``truth``)."""
    out = copy.deepcopy(config)
    for equation in out["model"]["equations"]:
        if equation["target"] in truth["targets"]:
            for component in equation["components"]:
                component["adjustable"] = component["term"] == truth["component"]
            equation["adjustments"] = [f"abs({truth['function']})"]
    return out


def pinned(report, truth: dict) -> dict:
    """Per target of the truth: the oracle's exponent, its half-width and whether it pins the law."""
    gaps = {g.target: g for g in report.equations}
    out = {}
    for target in truth["targets"]:
        g = gaps[target]
        half = (g.naming or {}).get("half_width") if g.significant else None
        ok = g.exponent is not None and half is not None and \
            abs(g.exponent - truth["exponent"]) + half - TOLERANCE <= TOLERANCE
        out[target] = {"exponent": g.exponent, "half_width": half, "pins": bool(ok)}
    return out


def identifiable(config: dict, truth: dict, data, validation) -> dict:
    """The oracle on a case (its ``config`` and records ``data``, ``validation``: paths or frames):
    ``identifiable`` when every target of the truth pins the law (:func:`pinned`)."""
    from msam_torch.diagnosis import diagnose

    report = diagnose(oracle_config(config, truth), data=data, validation=validation, options=ORACLE_OPTIONS)
    targets = pinned(report, truth)
    return {"identifiable": all(t["pins"] for t in targets.values()), "targets": targets}
