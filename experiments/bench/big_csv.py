"""A 3.5 M-row CSV through ``msam diagnose`` (issue 18, acceptance 5): wall time and peak memory
against the limits (5 minutes on 2 cores, 4 GB), and the verdict beside that of a 35 k-row record
of the same system.

The system is a withheld-effect case of :mod:`msam_torch.data.systems` (default: a mass-spring-damper
with unmodelled quadratic drag, multisine force), run for ``--seconds``. It is simulated on the
small record's grid (:func:`msam_torch.data.systems.measure`, dopri5 at tolerance 1e-10); the large
record samples the same trajectory ``rows / small`` times finer by quintic Hermite interpolation
of x, x_dot and x_ddot (``scipy.interpolate.BPoly.from_derivatives``, error far below the noise)
with the force evaluated exactly. Each record gets its own white noise of ``--noise`` times the
displacement's standard deviation. The starting model lacks the effect; only ``x`` and ``u`` are
measured (columns ``t, x, u``), so the diagnosis estimates the derivatives.

Each ``msam diagnose`` (and, with ``--adapt``, ``msam run`` on the large record) runs as a child
process (one torch thread); its peak resident memory is the child's own (``os.wait4``), and the
load average is printed beside the time because the machine may be shared.

    python -m experiments.bench.big_csv [--rows 3500000] [--small 35000] [--seconds 350] [--adapt]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

from msam_torch.data.systems import WITHHELD
from msam_torch.data.withheld import finer_records

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
LIMIT_SECONDS, LIMIT_BYTES = 300.0, 4 * 2**30
PROGRESS = re.compile(r"\(\d+ s(, about \d+ s left)?\)$")


def progress(lines: list[str]) -> int:
    """Progress lines on stderr: 'stage k/n what (elapsed s[, about r s left])'."""
    return sum(bool(PROGRESS.search(line)) for line in lines)


def timed(command: list[str], log: Path) -> dict:
    """Run ``msam <command>`` as a child process; its exit status, wall and CPU time, peak resident
    memory (the child's own) and the load average before and after."""
    load = os.getloadavg()
    with open(log, "w") as handle:
        started = time.perf_counter()
        child = subprocess.Popen([sys.executable, "-m", "msam_torch", *command], env=ENV, stdout=handle,
                                 stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - started
    return {"status": os.waitstatus_to_exitcode(status), "seconds": wall, "cpu": usage.ru_utime + usage.ru_stime,
            "peak_bytes": usage.ru_maxrss * 1024,
            "load": (load[0], os.getloadavg()[0]), "log": log.read_text()}


def measure_record(folder: Path, frame: pd.DataFrame, case: str, name: str, adapt: bool) -> dict:
    """Write the record and its config to ``folder``, run ``msam diagnose`` (and ``msam run`` when
    ``adapt``); time, peak memory, verdict (and adapted equation)."""
    frame.to_csv(folder / f"{name}.csv", index=False)
    config = {"model": WITHHELD[case].model,
              "data": {"file": f"{name}.csv", "time": "t", "columns": {"x": "x", "u": "u"}}}
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(config))
    out = folder / f"{name}_diagnosis"
    run = timed(["diagnose", str(folder / f"{name}.yaml"), "--out", str(out), "--threads", "1"], folder / f"{name}.log")
    report = json.loads((out / "gap_report.json").read_text()) if run["status"] == 0 else {}
    lines = run.pop("log").strip().splitlines() or ["?"]
    runs = {"diagnose": {**run, "verdict": report.get("verdict", lines[-1]),
                         "decimation": (report.get("data", {}).get("train", {}).get("decimated", {}).get("factor", 1),
                                        report["equations"][0]["estimator"]["decimation"] if report else None),
                         "progress_lines": progress(lines)}}
    if adapt:
        run = timed(["run", str(folder / f"{name}.yaml"), "--out", str(folder / f"{name}_run"), "--no-tensorboard"],
                    folder / f"{name}_run.log")
        lines = run.pop("log").strip().splitlines() or ["?"]
        adapted = [line.split(":", 1)[1].strip() for line in lines if line.startswith("adapted:")]
        runs["run"] = {**run, "verdict": adapted[0] if adapted else lines[-1], "decimation": None,
                       "progress_lines": progress(lines)}
    return {"rows": len(frame), "megabytes": (folder / f"{name}.csv").stat().st_size / 1e6, **runs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=3_500_000, help="rows of the large record")
    parser.add_argument("--small", type=int, default=35_000, help="rows of the small record (the simulation grid)")
    parser.add_argument("--seconds", type=float, default=350.0, help="record length in the system's time units")
    parser.add_argument("--case", default="msd_quadratic_drag", choices=sorted(WITHHELD))
    parser.add_argument("--noise", type=float, default=0.01, help="noise, a share of the displacement's std")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--adapt", action="store_true", help="also time msam run on the large record")
    parser.add_argument("--keep", help="folder for the records and reports (default: a temporary one, removed)")
    args = parser.parse_args()
    made = time.perf_counter()
    frames = finer_records(args.case, args.seconds, args.small, args.rows, args.noise, args.seed)
    print(f"{args.case}: {args.seconds:g} time units, records of {args.small} and {args.rows} rows generated in "
          f"{time.perf_counter() - made:.0f} s; {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory(prefix="msam-big-csv-") as scratch:
        folder = Path(args.keep or scratch)
        folder.mkdir(parents=True, exist_ok=True)
        results = {label: measure_record(folder, frames.pop(n), args.case, label, args.adapt and label == "large")
                    for label, n in (("small", args.small), ("large", args.rows))}
    print("record | rows | CSV MB | command | exit | wall s | CPU s | peak RSS GB | load avg before, after (1 min) | "
          "decimation (record, weak form) | progress lines | verdict or adapted equation")
    for label, r in results.items():
        for command in ("diagnose", "run"):
            if command in r:
                c = r[command]
                print(f"{label} | {r['rows']} | {r['megabytes']:.0f} | {command} | {c['status']} | {c['seconds']:.1f} | "
                      f"{c['cpu']:.1f} | {c['peak_bytes'] / 2**30:.2f} | {c['load'][0]:.1f}, {c['load'][1]:.1f} | "
                      f"{c['decimation']} | {c['progress_lines']} | {c['verdict']}")
    large, small = results["large"]["diagnose"], results["small"]["diagnose"]
    checks = {f"wall time {large['seconds']:.0f} s < {LIMIT_SECONDS:.0f} s": large["seconds"] < LIMIT_SECONDS,
              f"peak memory {large['peak_bytes'] / 2**30:.2f} GB < {LIMIT_BYTES / 2**30:.0f} GB":
                  large["peak_bytes"] < LIMIT_BYTES,
              "both diagnoses exit 0": large["status"] == small["status"] == 0,
              "same verdict as the small record": large["verdict"] == small["verdict"]}
    for what, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}: {what}")
    sys.exit(0 if all(checks.values()) else 1)


if __name__ == "__main__":
    main()
