"""The reference of every config key, generated from the schema (:class:`~msam_torch.config.schema.Config`):
``python -m msam_torch.config.keys`` prints it as Markdown (the docs publish it as
``docs/config-keys.md``, and a test holds the two equal), so no key can be missing from it."""
from __future__ import annotations

import json

from msam_torch.config.schema import Config


def type_text(node: dict, defs: dict) -> str:
    """A key's type as a reader would write it."""
    if "$ref" in node:
        return "section" if "properties" in defs[node["$ref"].split("/")[-1]] else "value"
    if "enum" in node:
        return " \\| ".join(f"`{v}`" for v in node["enum"])
    if "const" in node:
        return f"`{node['const']}`"
    if "anyOf" in node:
        kinds = [type_text(n, defs) for n in node["anyOf"] if n.get("type") != "null"]
        return " or ".join(dict.fromkeys(kinds)) + (" or null" if any(n.get("type") == "null" for n in node["anyOf"]) else "")
    kind = node.get("type", "any")
    if kind == "array":
        return f"list of {type_text(node.get('items', {}), defs)}"
    if kind == "object":
        extra = node.get("additionalProperties")
        return f"mapping of name to {type_text(extra, defs)}" if isinstance(extra, dict) else "mapping"
    return {"string": "text", "number": "number", "integer": "integer", "boolean": "true/false"}.get(kind, kind)


def _section(node: dict, defs: dict) -> dict:
    """The definition a key's value refers to (a section), else {}."""
    for alt in [node, *node.get("anyOf", [])]:
        if "$ref" in alt:
            return defs[alt["$ref"].split("/")[-1]]
    return {}


def _children(node: dict, defs: dict) -> list[tuple[str, dict]]:
    """(suffix, schema) of the keys below a key: a section's own keys, a list's or a mapping's items."""
    for alt in node.get("anyOf", []):
        if alt.get("type") != "null":
            node = alt
            break
    if "$ref" in node:
        return [(f".{k}", v) for k, v in defs[node["$ref"].split("/")[-1]].get("properties", {}).items()]
    if node.get("type") == "array" and isinstance(node.get("items"), dict) and "$ref" in node["items"]:
        return [(f"[].{k}", v) for k, v in defs[node["items"]["$ref"].split("/")[-1]].get("properties", {}).items()]
    extra = node.get("additionalProperties")
    if isinstance(extra, dict) and "$ref" in extra:
        return [(f".<name>.{k}", v) for k, v in defs[extra["$ref"].split("/")[-1]].get("properties", {}).items()]
    return []


def rows(schema: dict | None = None) -> list[tuple[str, str, str, str]]:
    """(key, type, default, description) of every key of a config, depth first, in the schema's order."""
    schema = Config.model_json_schema() if schema is None else schema
    defs = schema.get("$defs", {})
    out = []

    def walk(prefix: str, properties: list[tuple[str, dict]]):
        for suffix, node in properties:
            key = f"{prefix}{suffix}".lstrip(".")
            default = f"`{json.dumps(node['default'])}`" if "default" in node else ""
            described = node.get("description") or _section(node, defs).get("description", "")
            out.append((key, type_text(node, defs), default, " ".join(described.split())))
            walk(key, _children(node, defs))

    walk("", [(f".{k}", v) for k, v in schema["properties"].items()])
    return out


def markdown() -> str:
    """The reference page: one row per key."""
    lines = ["# Config keys", "",
             "Every key of a config, generated from the schema (`python -m msam_torch.config.keys`). "
             "`[]` stands for an item of a list, `<name>` for a key of a mapping. Strategy keys take a "
             "registered name or, from Python, an object ([Strategies](api/strategies.md)).", "",
             "| key | type | default | meaning |", "|---|---|---|---|"]
    lines += [f"| `{k}` | {t} | {d} | {m.replace('|', chr(92) + '|')} |" for k, t, d, m in rows()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown(), end="")
