"""Several effects in turn on generated cases (:mod:`msam_torch.diagnosis.effects.multi`): zoo cases that
withhold two effects at once (:func:`msam_torch.zoo.generate_pair`), and single-effect and null
cases of the ordinary zoo (:func:`msam_torch.zoo.generate`) to count spurious effects added in turn.

Per case: the effects ``msam diagnose`` added in turn (its report's ``in_turn``), scored by
:func:`msam_torch.zoo.score.score`: two-effect cases count how many withheld effects were found
(right equation, name, component, function and exponent, in any order); every case counts the
effects added that match nothing withheld (spurious). Cases are written to CSV files and diagnosed
from those paths, with the default options.

Seeds: development used pair seeds 0-5 and zoo seeds 0-5; the figures in docs/diagnose.md come
from pair seeds 5000-5019 and zoo seeds 5000-5009, not looked at before.

Run (about 25 s of CPU per case; minutes on 2 busy cores):
    python -m experiments.suites.zoo_pairs --pairs 20 --pair-seed-start 5000 --singles 10 --single-seed-start 5000
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

from msam_torch.diagnosis import diagnose  # noqa: E402
from msam_torch.zoo import generate, generate_pair, score  # noqa: E402


class Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise Timeout()


def run_case(case, timeout: int) -> dict:
    """Diagnose one case from files; its score and the effects added in turn."""
    row = {"seed": case.seed, "system": case.metadata["system"], "noise": case.metadata["noise"],
           "kind": case.truth["kind"],
           "withheld": [e["name"] for e in case.truth.get("effects", [case.truth] if case.truth.get("name") else [])]}
    signal.alarm(timeout)
    try:
        with tempfile.TemporaryDirectory() as folder:
            config = case.write(folder)
            started = time.perf_counter()
            report = diagnose(config, data=Path(folder) / "train.csv", validation=Path(folder) / "validation.csv")
            row["seconds"] = time.perf_counter() - started
        row["score"] = score.score(report, case.truth)
        row["added"] = [(s["target"], s["effect"], round(s["exponent"], 3)) for s in report.in_turn["effects"]]
        row["stopped"] = report.in_turn["stopped"]
    except Timeout:
        row["error"] = f"timeout after {timeout} s"
    except Exception as exc:  # a case the diagnosis cannot take is a finding, not a crash of the run
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
    finally:
        signal.alarm(0)
    return row


def summary(rows: list[dict]) -> str:
    """Both found / one found / spurious additions per kind of case (errors count as not found)."""
    lines = ["| cases | kind | all withheld found | at least one found | cases with a spurious effect added | "
             "errors | s per case |", "|---|---|---|---|---|---|---|"]
    for kind in sorted({r["kind"] for r in rows}):
        part = [r for r in rows if r["kind"] == kind]
        done = [r for r in part if "score" in r]
        rate = lambda hits, n: f"{hits}/{n} ({100 * hits / n:.0f} %)" if n else "-"
        found = rate(sum(bool(r["score"].get("all_found")) for r in done), len(part)) if kind == "several" else "-"
        one = rate(sum(r["score"].get("found", 0) > 0 for r in done), len(part)) if kind == "several" else "-"
        spurious = rate(sum(r["score"]["spurious"] > 0 for r in done), len(done))
        seconds = [r["seconds"] for r in done]
        lines.append(f"| {len(part)} | {kind} | {found} | {one} | {spurious} | {len(part) - len(done)} | "
                     f"{sum(seconds) / max(len(seconds), 1):.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=24, help="two-effect cases")
    parser.add_argument("--pair-seed-start", type=int, default=5000)
    parser.add_argument("--singles", type=int, default=0, help="ordinary zoo cases (single effect or null)")
    parser.add_argument("--single-seed-start", type=int, default=5000)
    parser.add_argument("--timeout", type=int, default=180, help="seconds per case")
    parser.add_argument("--out", help="JSON lines file of the rows")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    signal.signal(signal.SIGALRM, _alarm)
    cases = [("pair", s) for s in range(args.pair_seed_start, args.pair_seed_start + args.pairs)]
    cases += [("single", s) for s in range(args.single_seed_start, args.single_seed_start + args.singles)]
    rows = []
    for kind, seed in cases:
        case = generate_pair(seed) if kind == "pair" else generate(seed)
        row = run_case(case, args.timeout)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")
    print(f"\nseeds: pairs {args.pair_seed_start}..{args.pair_seed_start + args.pairs - 1}, "
          f"singles {args.single_seed_start}..{args.single_seed_start + args.singles - 1}")
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
