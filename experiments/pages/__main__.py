"""Write one results page of docs/results/ from its measurements.

    python -m experiments.pages {zoo,real-data,performance,suite} [--steps NAME ...] [--quick]
        [--page PATH] [--results DIR] [-- ARGS passed to every step run]

Runs the page's steps (experiments/pages/plans.py; ``--steps`` names some, ``--steps`` alone none),
keeps each step's record in ``--results`` as it ends, then writes the page: the template
(experiments/pages/templates/<page>.md, prose without figures) with the stamp and each step's
output and provenance filled in. A step not measured yet is named as such, and the page says it
is partial; running the command again measures what is missing (``--steps`` re-measures).
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from itertools import pairwise
from pathlib import Path

from experiments.pages.plans import PAGES, Page, Step
from experiments.pages.stamp import ROOT, provenance, run_step, stamp
from msam_torch.run.outputs import write_atomic

TEMPLATES = Path(__file__).resolve().parent / "templates"
MARKER = re.compile(r"\{\{(stamp|partial|step:[\w-]+)\}\}")


def demoted(markdown: str, top: int = 3) -> str:
    """The output's headings moved down so that its highest is ``top`` (the page's own are above)."""
    levels = [len(m) for m in re.findall(r"^(#+) ", markdown, flags=re.MULTILINE)]
    shift = max(0, top - min(levels)) if levels else 0
    return re.sub(r"^(#+) ", lambda m: "#" * (len(m.group(1)) + shift) + " ", markdown, flags=re.MULTILINE)


def spaced(markdown: str) -> str:
    """A blank line between a table and the text next to it (a table must stand in a block of its own)."""
    lines = markdown.splitlines()
    out = lines[:1]
    for before, line in pairwise(lines):
        if before.strip() and line.strip() and before.startswith("|") != line.startswith("|"):
            out.append("")
        out.append(line)
    return "\n".join(out)


def section(step: Step, record: dict | None, command: str) -> str:
    if record is None:
        return f"*Not measured yet: `{command} --steps {step.name}` measures it.*"
    output = record["output"].strip()
    body = f"```text\n{output}\n```" if step.text else spaced(demoted(output))
    failed = f"**The command failed (exit status {record['returncode']}); its output so far:**\n\n" \
        if record["returncode"] else ""
    return f"{failed}{body}\n\n{provenance(record)}"


def unfinished(record: dict | None) -> bool:
    """Not measured, failed, or a partial run (the zoo's, stopped before its last case)."""
    return record is None or bool(record["returncode"]) or "(partial" in record["output"]


def render(name: str, page: Page, records: dict, argv: list[str]) -> str:
    command = f"python -m experiments.pages {name}"
    missing = [s.name for s in page.steps if unfinished(records.get(s.name))]
    note = f"**Partial page:** {', '.join(missing)} not measured, failed or partial (see below); `{command}` " \
        "measures what is missing." if missing else ""
    fill = {"stamp": stamp(argv), "partial": note}
    fill.update({f"step:{s.name}": section(s, records.get(s.name), command) for s in page.steps})
    text = MARKER.sub(lambda m: fill[m.group(1)], (TEMPLATES / f"{name}.md").read_text())
    return re.sub(r"\n{3,}", "\n\n", text)


def main(argv: list[str]) -> int:
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    ours = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("page", choices=list(PAGES))
    parser.add_argument("--steps", nargs="*", default=None, help="steps to (re-)measure (default: those not measured)")
    parser.add_argument("--quick", action="store_true", help="each step's tiny run (the tests' check of the page)")
    parser.add_argument("--page", dest="path", type=Path, default=None, help="default: docs/results/<page>.md")
    parser.add_argument("--results", type=Path, default=None, help="default: experiments/results/pages/<page>")
    args = parser.parse_args(ours)
    page = PAGES[args.page]
    results = args.results or Path("experiments/results") / ("pages-quick" if args.quick else "pages") / args.page
    unknown = set(args.steps or []) - {s.name for s in page.steps}
    if unknown:
        parser.error(f"unknown step {min(unknown)!r} (steps: {', '.join(s.name for s in page.steps)})")
    record_path = lambda step: ROOT / results / f"{step.name}.json"
    records = {s.name: json.loads(record_path(s).read_text()) for s in page.steps if record_path(s).exists()}
    for step in page.steps:
        chosen = step.name in args.steps if args.steps is not None else unfinished(records.get(step.name))
        step_args = step.quick if args.quick else step.args
        if chosen and step_args is not None:
            print(f"[{args.page}] {step.name} ...", file=sys.stderr, flush=True)
            arguments = [a.replace("{results}", str(results)) for a in step_args] + extra
            records[step.name] = run_step(arguments, record_path(step))
    path = args.path or ROOT / "docs" / "results" / f"{args.page}.md"
    write_atomic(path, render(args.page, page, records, argv))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
