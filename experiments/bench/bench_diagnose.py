"""Diagnosis benchmark and record-length invariance: the default ``diagnose`` of a 2-state case
(mass-spring-damper with Coulomb friction withheld, position and force measured, 1 % noise) on
a 2,000-sample record, on records 10x (and ``--longer``) longer at the same sampling period, and
on one sampled 10x faster over the same time; each run's wall time, its ratio to the 2,000-sample
run's, the verdict, the exponent with its 90 % bootstrap interval, the test-function half-width and
the derivative window chosen, and whether the record gives the 1x verdict with an exponent inside
the 1x record's interval, and with the two exponents' difference inside its own interval
(:func:`agrees_jointly`).

    python -m experiments.bench.bench_diagnose [--threads 1] [--longer 10 50] [--repeats 3]

The time is the diagnosis itself (``GapReport.seconds``: data loading excluded), the median of
``--repeats`` runs. Each record runs in a process of its own, so that its peak resident memory
(``ru_maxrss``: the record, its diagnosis and the interpreter with torch) is its own.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import resource
import statistics
from concurrent.futures import ProcessPoolExecutor

import torch

from msam_torch.data.withheld import withheld_records
from msam_torch.diagnosis import diagnose

CASE = "msd_coulomb"
NOISE = 0.01


def run(length: float, faster: int, repeats: int) -> dict:
    w, (train, held_out) = withheld_records(length, faster)
    config = {"model": w.model, "data": {"parametric_error": 0.2, "seed": 1}}
    reports = [diagnose(config, data=train, validation=held_out) for _ in range(repeats)]
    g = reports[0].equations[0]
    interval = next((term["exponent_interval"] for term in g.intervals if term["exponent_interval"]), None)
    windows = [d.get("window") for d in g.estimator["derivatives"].values()] \
        if isinstance(g.estimator["derivatives"], dict) else []
    return {"samples": int(train.t.numel()), "seconds": statistics.median(r.seconds for r in reports),
            "verdict": reports[0].verdict, "exponent": g.exponent, "interval": interval,
            "half_width": g.estimator["half_width"], "decimation": g.estimator["decimation"],
            "window": ", ".join(str(w) for w in windows if w) or "-",
            "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}


def isolated(length: float, faster: int, repeats: int, threads: int) -> dict:
    """:func:`run` in a fresh process (its peak memory its own)."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=torch.set_num_threads,
                             initargs=(threads,)) as pool:
        return pool.submit(run, length, faster, repeats).result()


def agrees(row: dict, base: dict) -> bool:
    """Same verdict as ``base``, and an exponent inside ``base``'s interval (or neither has one)."""
    if row["exponent"] is None or base["interval"] is None:
        return row["verdict"] == base["verdict"] and row["exponent"] is None and base["exponent"] is None
    low, high = base["interval"]
    return row["verdict"] == base["verdict"] and low <= row["exponent"] <= high


def agrees_jointly(row: dict, base: dict) -> bool:
    """Same verdict as ``base``, and the two exponents' difference within its own 90 % interval:
    each record is a draw with an interval of its own, so the difference's half-width is the root
    sum of squares of the two intervals' half-widths on the sides facing each other (one exponent
    inside the other's interval ignores the second's uncertainty and fails more often than 10 %)."""
    if row["interval"] is None or base["interval"] is None:
        return agrees(row, base)
    above = row["exponent"] >= base["exponent"]
    base_half = (base["interval"][1] - base["exponent"]) if above else (base["exponent"] - base["interval"][0])
    row_half = (row["exponent"] - row["interval"][0]) if above else (row["interval"][1] - row["exponent"])
    return row["verdict"] == base["verdict"] and abs(row["exponent"] - base["exponent"]) <= math.hypot(base_half, row_half)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--longer", type=float, nargs="*", default=[10.0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rows = [("1x", isolated(1.0, 1, args.repeats, args.threads))]
    rows += [(f"{k:g}x longer", isolated(k, 1, args.repeats, args.threads)) for k in args.longer]
    rows.append(("10x faster sampling", isolated(1.0, 10, args.repeats, args.threads)))
    base = rows[0][1]["seconds"]
    print(f"{CASE}, {100 * NOISE:g} % noise, {args.threads} torch threads, median of {args.repeats} runs")
    print("| record | samples | diagnosis s | ratio to 1x | peak memory GB | verdict | exponent | interval | half-width "
          "| decimation | derivative window | 1x verdict, exponent in 1x interval | 1x verdict, difference within its "
          "interval |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label, r in rows:
        exponent = "-" if r["exponent"] is None else f"{r['exponent']:.3f}"
        interval = "-" if r["interval"] is None else "{:.3f} to {:.3f}".format(*r["interval"])
        print(f"| {label} | {r['samples']} | {r['seconds']:.2f} | {r['seconds'] / base:.2f} | {r['peak_gb']:.2f} "
              f"| {r['verdict']} | "
              f"{exponent} | {interval} | {r['half_width']:.3g} | {r['decimation']} | {r['window']} | "
              f"{'yes' if agrees(r, rows[0][1]) else 'NO'} | {'yes' if agrees_jointly(r, rows[0][1]) else 'NO'} |")


if __name__ == "__main__":
    main()
