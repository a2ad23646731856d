"""The test suite's tiers: how many tests each holds, how they end, and how long each tier takes.

    python -m experiments.suites.tiers [default slow] [--paths tests/cli ...]

Each tier runs as CI runs it (``python -m pytest -q`` for the default tier, ``-m slow`` for the
slow tier), in a child process whose wall time is measured here; pytest's JUnit XML gives the
outcome of every test and its time, summed per test folder. Printed as Markdown: one row per tier,
then per folder, then the slowest tests of each tier.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from xml.etree import ElementTree

ROOT = Path(__file__).resolve().parents[2]
TIERS = {"default": [], "slow": ["-m", "slow"]}
OUTCOMES = ("passed", "failed", "errors", "skipped")


def outcome(case: ElementTree.Element) -> str:
    """passed, failed, errors or skipped, from a JUnit ``testcase`` element."""
    tags = {child.tag for child in case}
    return "failed" if "failure" in tags else "errors" if "error" in tags else "skipped" if "skipped" in tags \
        else "passed"


def folder(classname: str) -> str:
    """The test folder of a JUnit class name (``tests.cli.test_main.TestX`` -> ``tests/cli``)."""
    parts: list[str] = []
    for part in classname.split("."):
        if not ROOT.joinpath(*parts, part).is_dir():
            break
        parts.append(part)
    return "/".join(parts) or "(collection)"


def run_tier(tier: str, paths: list[str]) -> dict:
    """One tier in a child process: wall time, exit status and every test's (folder, name, outcome, s)."""
    with tempfile.TemporaryDirectory() as scratch:
        xml = Path(scratch) / "junit.xml"
        command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *TIERS[tier],
                   f"--junitxml={xml}", *paths]
        started = time.perf_counter()
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "CI": "true"}, check=False)
        wall = time.perf_counter() - started
        cases = ElementTree.parse(xml).getroot().iter("testcase") if xml.exists() else []
        tests = [(folder(c.get("classname", "")), c.get("name"), outcome(c), float(c.get("time", 0))) for c in cases]
    summary = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr.strip()[-300:]
    return {"tier": tier, "wall_s": wall, "returncode": done.returncode, "tests": tests, "summary": summary}


def tier_table(runs: list[dict]) -> str:
    lines = ["| tier | tests | " + " | ".join(OUTCOMES) + " | wall time s | pytest's last line |",
             "|" + "---|" * (len(OUTCOMES) + 4)]
    for run in runs:
        counts = [sum(t[2] == o for t in run["tests"]) for o in OUTCOMES]
        lines.append(f"| {run['tier']} | {len(run['tests'])} | " + " | ".join(map(str, counts))
                     + f" | {run['wall_s']:.1f} | {run['summary']} |")
    return "\n".join(lines)


def folder_table(runs: list[dict]) -> str:
    lines = ["| tier | test folder | tests | seconds in its tests |", "|---|---|---|---|"]
    for run in runs:
        folders = defaultdict(list)
        for where, _, _, seconds in run["tests"]:
            folders[where].append(seconds)
        lines += [f"| {run['tier']} | {where} | {len(s)} | {sum(s):.1f} |" for where, s in sorted(folders.items())]
    return "\n".join(lines)


def slowest(runs: list[dict], count: int) -> str:
    lines = ["| tier | test | seconds |", "|---|---|---|"]
    for run in runs:
        top = sorted(run["tests"], key=lambda t: -t[3])[:count]
        lines += [f"| {run['tier']} | `{where}::{name}` | {seconds:.1f} |" for where, name, _, seconds in top]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tiers", nargs="*", help=f"of {', '.join(TIERS)} (default: both)")
    parser.add_argument("--paths", nargs="*", default=[], help="test files or folders (default: the whole suite)")
    parser.add_argument("--slowest", type=int, default=5, help="slowest tests listed per tier")
    args = parser.parse_args()
    if set(args.tiers) - set(TIERS):
        parser.error(f"unknown tier {min(set(args.tiers) - set(TIERS))!r} (tiers: {', '.join(TIERS)})")
    runs = []
    for tier in args.tiers or list(TIERS):
        runs.append(run_tier(tier, args.paths))
        print(f"[{tier}] {runs[-1]['summary']} ({runs[-1]['wall_s']:.0f} s)", file=sys.stderr, flush=True)
    print(f"## Tiers\n\n{tier_table(runs)}\n\n## Per test folder\n\n{folder_table(runs)}\n\n"
          f"## Slowest tests\n\n{slowest(runs, args.slowest)}")
    return 0  # failed tests are findings of the table, not a failure of the measurement


if __name__ == "__main__":
    sys.exit(main())
