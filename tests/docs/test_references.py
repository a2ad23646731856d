"""The generated reference pages are the published ones, and each holds every item of its source:
an option, a catalogue entry or a report field added without regenerating its page fails here."""
import argparse
from pathlib import Path

import pytest

from msam_torch.cli import usage as cli_reference
from msam_torch.cli.main import build_parser
from msam_torch.diagnosis.catalogue import listing as catalogue_reference
from msam_torch.diagnosis.catalogue.entries import bundled
from msam_torch.diagnosis.report import fields
from msam_torch.diagnosis.report.json_schema import gap_report_schema

DOCS = Path(__file__).resolve().parents[2] / "docs" / "reference"


@pytest.mark.parametrize("page, generator", [
    ("cli.md", cli_reference), ("catalogue.md", catalogue_reference), ("report-fields.md", fields)])
def test_the_published_page_is_the_generated_one(page, generator):
    """Regenerate with ``python -m <generator module> > docs/reference/<page>``."""
    assert (DOCS / page).read_text() == generator.markdown()


def test_every_option_of_every_command_is_in_the_cli_reference():
    page = (DOCS / "cli.md").read_text()
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert set(commands) == {"run", "diagnose"}
    flags = [f for sub in commands.values() for a in sub._actions for f in a.option_strings if f not in ("-h", "--help")]
    assert {"--max-effects", "--validate", "--max-seconds", "--no-plots"} <= set(flags)
    assert [f for f in flags if f"`{f}" not in page] == []
    assert all(f"## `msam {name}`" in page for name in commands)


def test_every_bundled_effect_is_in_the_catalogue_reference():
    page = (DOCS / "catalogue.md").read_text()
    names = [entry.name for entry in bundled()]
    assert {"Coulomb friction", "Torricelli outflow", "radiation"} <= set(names)
    assert [n for n in names if f"| {n} |" not in page] == []


def test_every_report_field_is_in_the_report_reference():
    schema = gap_report_schema()
    page = (DOCS / "report-fields.md").read_text()
    records = {name: d for name, d in schema["$defs"].items() if "properties" in d}
    assert {"EquationGap", "Where", "Checks", "Confidence"} <= set(records)
    for name, definition in [("The document", schema), *records.items()]:
        section = page.split(f"## {name}\n", 1)[1].split("\n## ", 1)[0]
        assert [f for f in definition["properties"] if f"| `{f}` |" not in section] == [], name
