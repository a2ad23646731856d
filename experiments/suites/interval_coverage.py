"""Do the diagnosis's exponent intervals hold the truth as often as they say?

    python -m experiments.suites.interval_coverage [--cases msd_coulomb ...] [--noise 0.01 0.05]
        [--draws 20] [--seed-start 100] [--workers 2] [--save rows.json]
    python -m experiments.suites.interval_coverage --rows rows.json   # the table of saved rows again

For each withheld-effect case (``msam_torch.data.systems.WITHHELD``, data as the withheld-effect suite
makes them: the position or level measured, the input exact, noise of the given share of each
measured signal's standard deviation, nominal theta exact) and noise level, ``--draws`` records
with independent noise draws (seeds from ``--seed-start``) are diagnosed with the default options.
Per row: how often the reported 90 % interval of the winning hypothesis's exponent holds the
true exponent and how often the naming interval (total exponent +- half-width) does, the spread
(standard deviation) of the estimates over the draws beside the median half-width of the
reported intervals, and the mean error of the estimates (their bias). The true total exponent is
the one the simulated system holds (``TRUTH``), on the signal the effect depends on. A law that is
not a power law has no such exponent: the simulated Coulomb friction is ``fc tanh(v / 0.01)``,
whose best power law over the record's speeds is not ``sign(v)``. So each row is also scored
against the exponent the diagnosis fits to the same record without noise (the estimator's own
limit, "noise-free fit"): what an interval about noise can be asked to hold.
"""
from __future__ import annotations

import argparse
import json
import statistics
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

from experiments.common import main_guard
from experiments.suites.withheld_effects import datasets
from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.systems import WITHHELD
from msam_torch.diagnosis import diagnose

# total exponent of each simulated effect on the signal it depends on (msam_torch.data.systems)
TRUTH = {"msd_coulomb": 0.0, "msd_quadratic_drag": 2.0, "msd_power_damping": 1.5, "msd_hardening": 3.0,
         "tank_torricelli": 0.5}


def trial(args) -> dict:
    case, noise, seed = args
    torch.set_num_threads(1)
    config = load_config({"model": WITHHELD[case].model, "data": {"parametric_error": 0.0, "seed": seed}})
    train, held_out = datasets(case, noise, seed, to_spec(config.model))
    gap = diagnose(config, data=train, validation=held_out).equations[0]
    row = {"case": case, "noise": noise, "seed": seed, "total": None}
    if gap.naming is None or gap.exponent is None:
        return row
    shift = gap.naming["total_exponent"] - gap.exponent  # the power of the signal in the component
    interval = next((t["exponent_interval"] for t in gap.intervals if t["exponent"] == gap.exponent), None)
    row.update(total=gap.naming["total_exponent"], half=gap.naming["half_width"],
               interval=None if interval is None else [v + shift for v in interval])
    return row


def summary(rows: list[dict], noise_free: dict[str, float | None]) -> str:
    """The table; ``noise_free``: per case, the total exponent fitted to the record without noise."""
    lines = ["| case | noise | estimated | 90 % interval holds truth | ... holds the noise-free fit | naming interval "
             "holds truth | spread of estimates | median half-width of 90 % intervals | mean error | mean error from "
             "the noise-free fit |", "|---|---|---|---|---|---|---|---|---|---|"]
    for key in sorted({(r["case"], r["noise"]) for r in rows}):
        group = [r for r in rows if (r["case"], r["noise"]) == key]
        truth, limit = TRUTH[key[0]], noise_free[key[0]]
        done = [r for r in group if r["total"] is not None]
        with_interval = [r for r in done if r["interval"] is not None]
        holds = lambda value: "-" if value is None else \
            f"{sum(r['interval'][0] <= value <= r['interval'][1] for r in with_interval)}/{len(with_interval)}"
        named = sum(abs(r["total"] - truth) <= r["half"] for r in done)
        estimates = [r["total"] for r in done]
        spread = statistics.stdev(estimates) if len(estimates) > 1 else float("nan")
        half = statistics.median((r["interval"][1] - r["interval"][0]) / 2 for r in with_interval) \
            if with_interval else float("nan")
        bias = lambda value: "-" if value is None or not estimates else f"{statistics.mean(estimates) - value:+.3f}"
        lines.append(f"| {key[0]} | {key[1]:g} | {len(done)}/{len(group)} | {holds(truth)} | {holds(limit)} | "
                     f"{named}/{len(done)} | {spread:.3f} | {half:.3f} | {bias(truth)} | {bias(limit)} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=list(TRUTH), choices=list(TRUTH))
    parser.add_argument("--noise", type=float, nargs="*", default=[0.01, 0.05])
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--seed-start", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--save", metavar="FILE", help="also write the rows and the noise-free fits to FILE (JSON)")
    parser.add_argument("--rows", metavar="FILE", help="print the table of the rows --save wrote (no diagnosis)")
    args = parser.parse_args()
    if args.rows:
        saved = json.loads(Path(args.rows).read_text())
        print(summary(saved["rows"], saved["noise_free"]))
        return
    if args.draws < 2:
        parser.error(f"--draws: at least 2 draws give a spread, not {args.draws}")
    if any(n < 0 for n in args.noise):
        parser.error(f"--noise: shares of a signal's standard deviation are at least 0, not {min(args.noise)}")
    if args.workers < 1:
        parser.error(f"--workers: at least 1, not {args.workers}")
    jobs = [(c, n, s) for c in args.cases for n in args.noise
            for s in range(args.seed_start, args.seed_start + args.draws)]
    with ProcessPoolExecutor(args.workers) as pool:
        limits = list(pool.map(trial, [(c, 0.0, args.seed_start) for c in args.cases]))
        rows = list(pool.map(trial, jobs))
    noise_free = {r["case"]: r["total"] for r in limits}
    if args.save:
        Path(args.save).write_text(json.dumps({"rows": rows, "noise_free": noise_free}, indent=1))
    print(summary(rows, noise_free))
    print("noise-free fits (total exponent): " + ", ".join(f"{r['case']} {r['total']:.3f}" if r["total"] is not None
                                                           else f"{r['case']} none" for r in limits))


if __name__ == "__main__":
    main_guard(main)
