"""The reference of the bundled effect catalogue, generated from ``catalogue.yaml``
(:func:`~msam_torch.diagnosis.catalogue.entries.bundled`): ``python -m
msam_torch.diagnosis.catalogue.listing`` prints it as Markdown (the docs publish it as
``docs/reference/catalogue.md``, and a test holds the two equal)."""
from __future__ import annotations

from msam_torch.config.schema import EffectConfig
from msam_torch.diagnosis.catalogue.entries import bundled


def _cell(value) -> str:
    """A field as a table cell: lists joined, ranges as [low, high], pipes escaped."""
    if isinstance(value, tuple) and all(isinstance(v, (int, float)) for v in value):
        text = f"[{value[0]:g}, {value[1]:g}]"
    elif isinstance(value, (list, tuple)):
        text = ", ".join(str(v) for v in value)
    elif isinstance(value, float):
        text = f"{value:g}"
    else:
        text = str(value)
    return text.replace("|", "\\|")


def markdown() -> str:
    """The reference page: the fields of an entry, then every bundled entry by domain."""
    fields = EffectConfig.model_fields
    lines = ["# Effect catalogue", "",
             ("The effects `msam diagnose` can name, generated from "
             "`msam_torch/diagnosis/catalogue/catalogue.yaml` "
             "(`python -m msam_torch.diagnosis.catalogue.listing`). How a fit is matched to an entry: "
             "[Naming an effect](../naming.md); adding entries of your own: "
             "[Add your own effect](../how-to/own-effect.md)."), "", "## Fields", "",
             "| field | meaning |", "|---|---|"]
    lines += [f"| `{name}` | {_cell(' '.join((f.description or '').split()))} |" for name, f in fields.items()]
    domains: dict[str, list[EffectConfig]] = {}
    for entry in bundled():
        domains.setdefault(entry.domain, []).append(entry)
    for domain, entries in domains.items():
        lines += ["", f"## {domain.replace('_', ' ').capitalize()}", "",
                  "| name | acts on | term | depends on | total exponent | sign | description | reference |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {e.name} | {_cell(e.acts_on)} | {_cell(e.term)} | {_cell(e.depends_on)} | {_cell(e.exponent)} "
                  f"| {e.sign} | {_cell(e.description)} | {_cell(e.reference)} |" for e in entries]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown(), end="")
