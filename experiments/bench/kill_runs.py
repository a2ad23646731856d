"""``kill -9`` at random points of ``msam run`` and ``msam diagnose`` (issue 18, acceptance 4).

Each command is first run to the end once to time it; then ``--runs`` runs of each are killed
with SIGKILL after a delay drawn uniformly from [0, 1.1 x that time] (so some kills land while
files are written, some after the end). Every other run writes into a folder that already holds a
complete earlier set. After each kill the output folder is checked and the counts are printed:

- truncated or invalid JSON (``result.json``, ``gap_report.json``);
- incomplete report sets: ``gap_report.json`` without ``report.md`` or a PNG it shows, or the
  reverse, or a temporary file inside the folder;
- hidden staging folders and temporary files of the killed run left beside or inside it (not part
  of any set; the next run into the folder removes them under its lock: checked at the end).

    python -m experiments.bench.kill_runs [--runs 20] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "harmonic.yaml"
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
COMMANDS = {"run": ["run", str(CONFIG), "adaptation.round_robin_steps=8", "adaptation.refinement_steps=20"],
            "diagnose": ["diagnose", str(CONFIG), "--threads", "1"]}


def start(command: str, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "msam_torch", *COMMANDS[command], "--out", str(out)], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def valid_json(path: Path) -> bool:
    try:
        return isinstance(json.loads(path.read_text()), dict)
    except (ValueError, OSError):
        return False


def inspect(command: str, out: Path) -> dict:
    """Problems found in ``out`` and beside it after a kill."""
    found = {"invalid_json": 0, "incomplete_set": 0, "leftovers": 0}
    found["leftovers"] += sum(1 for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))
    if not out.exists():
        return found
    names = {p.name for p in out.iterdir()}
    found["leftovers"] += sum(1 for n in names if n.endswith(".tmp"))
    main_file = "result.json" if command == "run" else "gap_report.json"
    if main_file in names and not valid_json(out / main_file):
        found["invalid_json"] += 1
    if command == "diagnose":
        shown = set(re.findall(r"\]\(([^)]+\.png)\)", (out / "report.md").read_text())) if "report.md" in names else set()
        complete = {"gap_report.json", "report.md"} <= names and shown <= names
        empty = not names
        stray = any(n.endswith(".tmp") or n.endswith(".tmp.png") for n in names)
        found["incomplete_set"] += int(not (complete or empty) or stray)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="killed runs of each command")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    totals = {"invalid_json": 0, "incomplete_set": 0, "leftovers": 0}
    with tempfile.TemporaryDirectory(prefix="msam-kill-") as tmp:
        tmp = Path(tmp)
        for command in COMMANDS:
            reference = tmp / f"{command}_reference"
            began = time.monotonic()
            assert start(command, reference).wait() == 0, f"msam {command} failed"
            seconds = time.monotonic() - began
            finished = 0
            for i in range(args.runs):
                out = tmp / f"{command}_{i}"
                if i % 2:  # a folder holding a complete earlier set
                    subprocess.run(["cp", "-r", str(reference), str(out)], check=True)
                process = start(command, out)
                time.sleep(rng.uniform(0, 1.1 * seconds))
                finished += process.poll() is not None
                process.send_signal(signal.SIGKILL)
                process.wait()
                for key, value in inspect(command, out).items():
                    totals[key] += value
            print(f"msam {command}: {args.runs} runs killed at random in [0, {1.1 * seconds:.1f}] s "
                  f"({finished} had already finished)")
        cleaned = True
        for command in COMMANDS:  # the next run into a folder removes what a killed one left
            out = tmp / f"{command}_0"
            if start(command, out).wait() != 0:
                raise SystemExit(f"msam {command} into a folder a killed run left failed")
            found = inspect(command, out)
            cleaned &= not any(found.values())
    print(f"truncated or invalid JSON files: {totals['invalid_json']}")
    print(f"incomplete report sets: {totals['incomplete_set']}")
    print(f"hidden staging folders / temporary files left by killed runs: {totals['leftovers']} "
          f"(removed by the next run into the folder: {'yes' if cleaned else 'NO'})")


if __name__ == "__main__":
    main()
