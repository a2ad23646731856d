"""A 3.5 M-row CSV through ``msam diagnose`` (issue 18, acceptance 5): wall time and peak memory
against the limits (5 minutes on 2 cores, 4 GB), and the verdict beside that of a 35 k-row record
of the same system.

The system is a withheld-effect case of :mod:`msam_torch.systems` (default: a mass-spring-damper
with unmodelled quadratic drag, multisine force), run for ``--seconds``. It is simulated on the
small record's grid (:func:`msam_torch.systems.measure`, dopri5 at tolerance 1e-10); the large
record samples the same trajectory ``rows / small`` times finer by quintic Hermite interpolation
of x, x_dot and x_ddot (``scipy.interpolate.BPoly.from_derivatives``, error far below the noise)
with the force evaluated exactly. Each record gets its own white noise of ``--noise`` times the
displacement's standard deviation. The starting model lacks the effect; only ``x`` and ``u`` are
measured (columns ``t, x, u``), so the diagnosis estimates the derivatives.

Each ``msam diagnose`` runs as a child process (one torch thread); its peak resident memory is
the child's own (``os.wait4``), and the load average is printed beside the time because the
machine may be shared.

    PYTHONPATH=. python experiments/big_csv.py [--rows 3500000] [--small 35000] [--seconds 350]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
import yaml
from scipy.interpolate import BPoly

from msam_torch.systems import SYSTEMS, WITHHELD, measure

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
LIMIT_SECONDS, LIMIT_BYTES = 300.0, 4 * 2**30


def records(case: str, seconds: float, small: int, rows: int, noise: float, seed: int) -> dict[int, pd.DataFrame]:
    """The small record (the simulation grid) and the large one (the same trajectory, finer)."""
    effect = WITHHELD[case]
    system = dataclasses.replace(SYSTEMS[effect.system], t_end=seconds, samples=small)
    truth = {k: v.numpy() for k, v in measure(system).items()}
    rng = np.random.default_rng(seed)
    out = {}
    for n in (small, rows):
        if n == small:
            t, x = truth["t"], truth["x"]
        else:
            t = np.linspace(0.0, seconds, n)
            x = BPoly.from_derivatives(truth["t"], np.stack([truth["x"], truth["x_dot"], truth["x_ddot"]], -1))(t)
        u = system.inputs["u"](torch.from_numpy(t)).numpy()
        out[n] = pd.DataFrame({"t": t, "x": x + noise * x.std() * rng.standard_normal(n), "u": u})
    return out


def diagnose(folder: Path, frame: pd.DataFrame, case: str, name: str) -> dict:
    """Write the record and its config to ``folder``, run ``msam diagnose``; time, peak memory, verdict."""
    frame.to_csv(folder / f"{name}.csv", index=False)
    config = {"model": WITHHELD[case].model,
              "data": {"file": f"{name}.csv", "time": "t", "columns": {"x": "x", "u": "u"}}}
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(config))
    out = folder / f"{name}_diagnosis"
    command = [sys.executable, "-m", "msam_torch", "diagnose", str(folder / f"{name}.yaml"), "--out", str(out),
               "--threads", "1"]
    load = os.getloadavg()
    with open(folder / f"{name}.log", "w") as log:
        started = time.perf_counter()
        child = subprocess.Popen(command, env=ENV, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - started
    child.returncode = os.waitstatus_to_exitcode(status)
    log_text = (folder / f"{name}.log").read_text()
    report = json.loads((out / "gap_report.json").read_text()) if child.returncode == 0 else {}
    estimator = report["equations"][0]["estimator"] if report else {}
    return {"rows": len(frame), "megabytes": (folder / f"{name}.csv").stat().st_size / 1e6, "status": child.returncode,
            "seconds": wall, "peak_bytes": usage.ru_maxrss * 1024, "load": (load, os.getloadavg()),
            "verdict": report.get("verdict", log_text.strip().splitlines()[-1] if log_text.strip() else "?"),
            "decimation": estimator.get("decimation"), "progress_lines": log_text.count("diagnose:")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=3_500_000, help="rows of the large record")
    parser.add_argument("--small", type=int, default=35_000, help="rows of the small record (the simulation grid)")
    parser.add_argument("--seconds", type=float, default=350.0, help="record length in the system's time units")
    parser.add_argument("--case", default="msd_quadratic_drag", choices=sorted(WITHHELD))
    parser.add_argument("--noise", type=float, default=0.01, help="noise, a share of the displacement's std")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", help="folder for the records and reports (default: a temporary one, removed)")
    args = parser.parse_args()
    made = time.perf_counter()
    frames = records(args.case, args.seconds, args.small, args.rows, args.noise, args.seed)
    print(f"{args.case}: {args.seconds:g} time units, records of {args.small} and {args.rows} rows generated in "
          f"{time.perf_counter() - made:.0f} s; {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory(prefix="msam-big-csv-") as scratch:
        folder = Path(args.keep or scratch)
        folder.mkdir(parents=True, exist_ok=True)
        runs = {label: diagnose(folder, frames.pop(n), args.case, label)
                for label, n in (("small", args.small), ("large", args.rows))}
    print("record | rows | CSV MB | exit | wall s | peak RSS GB | load avg before, after (1 min) | decimation | "
          "progress lines | verdict")
    for label, r in runs.items():
        print(f"{label} | {r['rows']} | {r['megabytes']:.0f} | {r['status']} | {r['seconds']:.1f} | "
              f"{r['peak_bytes'] / 2**30:.2f} | {r['load'][0][0]:.1f}, {r['load'][1][0]:.1f} | {r['decimation']} | "
              f"{r['progress_lines']} | {r['verdict']}")
    large = runs["large"]
    checks = {f"wall time {large['seconds']:.0f} s < {LIMIT_SECONDS:.0f} s": large["seconds"] < LIMIT_SECONDS,
              f"peak memory {large['peak_bytes'] / 2**30:.2f} GB < {LIMIT_BYTES / 2**30:.0f} GB":
                  large["peak_bytes"] < LIMIT_BYTES,
              "both exit 0": large["status"] == runs["small"]["status"] == 0,
              "same verdict as the small record": large["verdict"] == runs["small"]["verdict"]}
    for what, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}: {what}")
    sys.exit(0 if all(checks.values()) else 1)


if __name__ == "__main__":
    main()
