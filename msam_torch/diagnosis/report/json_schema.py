"""The JSON schema of ``gap_report.json``, generated from the report's types
(:class:`~msam_torch.diagnosis.report.gap_report.GapReport`, its equations and their
:mod:`records <msam_torch.diagnosis.report.records>`); ``python -m msam_torch.diagnosis.report.json_schema``
prints it (the docs publish it as ``docs/gap_report.schema.json``)."""
from __future__ import annotations

import json

from pydantic import TypeAdapter

from msam_torch.diagnosis.report.gap_report import SCHEMA_VERSION, GapReport

NOT_IN_JSON = ("series", "models", "accepted")  # arrays and models kept in memory only


def _non_finite(node):
    """A number may be written as "inf", "-inf" or "nan"."""
    if isinstance(node, dict):
        node = {k: _non_finite(v) for k, v in node.items()}
        if node.get("type") == "number":
            rest = {k: v for k, v in node.items() if k != "type"}
            return {"anyOf": [{"type": "number"}, {"enum": ["inf", "-inf", "nan"]}], **rest}
        return node
    if isinstance(node, list):
        return [_non_finite(v) for v in node]
    return node


def gap_report_schema() -> dict:
    """The JSON schema (draft 2020-12) of the document :meth:`GapReport.to_dict` writes."""
    schema = TypeAdapter(GapReport).json_schema(mode="serialization")
    for key in NOT_IN_JSON:
        schema["properties"].pop(key)
    schema["properties"] = {"version": {"const": SCHEMA_VERSION}, **schema["properties"]}
    schema["required"] = ["version", *schema["required"]]
    equation = schema["$defs"]["EquationGap"]
    equation["properties"]["verdict"] = {"type": "string", "description": "the verdict as text"}
    equation["required"].append("verdict")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "gap_report.json",
            **_non_finite(schema)}


if __name__ == "__main__":
    print(json.dumps(gap_report_schema(), indent=1))
