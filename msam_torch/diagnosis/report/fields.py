"""The reference of ``gap_report.json``'s fields, generated from its JSON schema
(:func:`~msam_torch.diagnosis.report.json_schema.gap_report_schema`, itself generated from the
report's types): ``python -m msam_torch.diagnosis.report.fields`` prints it as Markdown (the docs
publish it as ``docs/reference/report-fields.md``, and a test holds the two equal)."""
from __future__ import annotations

from msam_torch.config.keys import type_text
from msam_torch.diagnosis.report.json_schema import gap_report_schema


def _kind(node: dict, defs: dict) -> str:
    """A field's type, a record type named and linked to its table."""
    for alt in [node, node.get("items", {}), *node.get("anyOf", [])]:
        if "$ref" in alt:
            name = alt["$ref"].split("/")[-1]
            if "properties" in defs[name]:
                record = f"[{name}](#{name.lower()})"
                return f"list of {record}" if alt is node.get("items") else record
    return type_text(node, defs)


def _table(definition: dict, defs: dict) -> list[str]:
    """One row per field of a record: name, type, whether always present, description."""
    required = set(definition.get("required", []))
    rows = ["| field | type | always | meaning |", "|---|---|---|---|"]
    for name, node in definition.get("properties", {}).items():
        meaning = " ".join((node.get("description") or "").split()).replace("|", "\\|")
        rows.append(f"| `{name}` | {_kind(node, defs)} | {'yes' if name in required else ''} | {meaning} |")
    return rows


def markdown() -> str:
    """The page: the document's top-level fields, then each record type it refers to."""
    schema = gap_report_schema()
    defs = schema.get("$defs", {})
    lines = ["# Report fields", "",
             ("Every field of `gap_report.json`, generated from the report's types "
             "(`python -m msam_torch.diagnosis.report.fields`; the JSON schema itself: "
             "[gap_report.schema.json](../gap_report.schema.json)). A number that is not finite is "
             "written as the string `\"inf\"`, `\"-inf\"` or `\"nan\"`. What the fields mean in a "
             "verdict: [the report reference](report.md)."), "", "## The document", ""]
    lines += _table(schema, defs)
    for name, definition in sorted(defs.items()):
        if "properties" not in definition:
            continue
        description = " ".join((definition.get("description") or "").split())
        lines += ["", f"## {name}", "", *([description, ""] if description else []), *_table(definition, defs)]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown(), end="")
