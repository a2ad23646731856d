"""Withheld-effect suite for ``msam diagnose`` (issue 5), against a PySINDy discrepancy-model baseline.

Each case is a true system with a known effect (``msam_torch.data.systems.WITHHELD``); data are
simulated with it, and the starting model is given without it. Grid: noise 0, 1, 5 % (of each
measured signal's standard deviation), parametric error 0, 25, 50 % (docs/design.md 2.8, drawn per
seed), seeds 0..S-1. Only the displacement (level) and the input are measured; velocities and
accelerations are estimated (Savitzky-Golay, default window). Held-out data come from another
excitation of the same system.

Baseline (Kaheman et al. 2019): PySINDy's sequentially thresholded least squares fitted to the
residual of the nominal model (the same estimated derivative), with a library holding the same
candidate effects (every component times ``|f|^g`` for ``g`` in ``LIBRARY_EXPONENTS``, plus the
linear components to absorb parametric error), columns and residual standardised, threshold
``SINDY_THRESHOLD``. Its answer is the nonlinear term with the largest contribution, named with the
same catalogue; no nonlinear term means "no significant gap".

Run (about an hour on 2 busy cores; --quick: a few minutes):
    python -m experiments.suites.withheld_effects [--quick] [--seeds 10] [--workers 2] [--out runs/withheld]
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from msam_torch.config.schema import DataConfig, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import build_dataset
from msam_torch.data.systems import SYSTEMS, WITHHELD, measure
from msam_torch.diagnosis import DiagnoseOptions, Verdict, diagnose
from msam_torch.diagnosis.catalogue.entries import NOT_CATALOGUED, name_effect
from msam_torch.model.spec import ModelSpec
from msam_torch.run.adapt import nominal_parameters

NOISE = (0.0, 0.01, 0.05)
PARAMETRIC = (0.0, 0.25, 0.5)
LIBRARY_EXPONENTS = (-1.0, -0.5, 0.5, 1.0, 2.0)
# STLSQ on standardised library columns and residual; the best of a small grid (threshold 0.05 .. 0.4,
# ridge alpha 1e-3 .. 1) on seed 0 of six cases: tuned in the baseline's favour.
SINDY_THRESHOLD = 0.2
SINDY_ALPHA = 1.0
_SIMULATIONS: dict = {}


def simulations(case: str) -> list[dict]:
    """True trajectories of the training and held-out excitations (computed once per process)."""
    if case not in _SIMULATIONS:
        torch.set_num_threads(1)
        w = WITHHELD[case]
        _SIMULATIONS[case] = [{k: v.numpy() for k, v in measure(SYSTEMS[n], rtol=1e-8, atol=1e-10).items()}
                              for n in (w.system, w.held_out)]
    return _SIMULATIONS[case]


def _share(cache: dict) -> None:
    _SIMULATIONS.update(cache)


def datasets(case: str, noise: float, seed: int, spec: ModelSpec, window: int | None = None):
    w = WITHHELD[case]
    rng = np.random.default_rng(seed)
    out = []
    for name, sim in zip((w.system, w.held_out), simulations(case)):
        system = SYSTEMS[name]
        measured = {k: sim[k] + (0.0 if k in system.inputs else noise * sim[k].std() * rng.standard_normal(sim[k].size))
                    for k in system.measured}
        info = {"source": f"system:{name}", "noise": noise, "seed": seed}
        out.append(build_dataset(sim["t"], measured, DataConfig(derivatives="savgol", window=window), spec, info, torch.float64))
    return out


def expected_verdict(case: str) -> str:
    w = WITHHELD[case]
    return Verdict.EXPLAINED.text(w.expected) if w.kind == "in_catalogue" else w.expected


def success(case: str, verdict: str) -> bool:
    """In-catalogue and null: the exact verdict; out-of-catalogue: no confident (wrong) name."""
    if WITHHELD[case].kind == "out_of_catalogue":
        return not verdict.startswith(Verdict.EXPLAINED.text(""))
    return verdict == expected_verdict(case)


def sindy_verdict(spec: ModelSpec, parameters: dict, train) -> str:
    """PySINDy discrepancy model: STLSQ on the nominal model's residual with the candidate effects."""
    from pysindy.optimizers import STLSQ

    equation = spec.equations[0]
    s = {k: v.numpy() for k, v in train.signals.items()}
    values = {k: torch.as_tensor(v) for k, v in s.items()}
    theta = spec.theta(equation, parameters).numpy()
    nominal = sum(theta[i] * np.broadcast_to(np.asarray(c.term(values), dtype=float), s["t"].shape)
                  for i, c in enumerate(equation.components))
    residual = s[equation.target] - nominal
    columns, labels = [], []
    for i in equation.fixed:
        columns.append(np.broadcast_to(np.asarray(equation.components[i].term(values), dtype=float), s["t"].shape))
        labels.append(None)
    for i in equation.adjustable:
        term = np.asarray(equation.components[i].term(values), dtype=float)
        columns.append(term), labels.append(None)
        for f, adjustment in enumerate(equation.adjustments):
            magnitude = np.abs(np.asarray(adjustment(values), dtype=float))
            for g in LIBRARY_EXPONENTS:
                columns.append(term * np.maximum(magnitude, 1e-12) ** g)
                labels.append((i, f, g))
    library = np.stack(columns, -1)
    spread = library.std(0) + 1e-300
    target_spread = residual.std() + 1e-300
    optimizer = STLSQ(threshold=SINDY_THRESHOLD, alpha=SINDY_ALPHA).fit(library / spread, residual / target_spread)
    coef = np.asarray(optimizer.coef_).reshape(-1) * target_spread / spread
    contribution = np.abs(coef) * spread
    nonlinear = [k for k, lab in enumerate(labels) if lab is not None and coef[k] != 0]
    if not nonlinear:
        return Verdict.NO_GAP.text()
    k = max(nonlinear, key=lambda k: contribution[k])
    i, f, g = labels[k]
    name = name_effect(equation, i, f, g, float(coef[k]), float(theta[i]), spec)
    return Verdict.NOT_EXPLAINED.text() if name == NOT_CATALOGUED else Verdict.EXPLAINED.text(name)


def run_trial(args) -> dict:
    case, noise, error, seed, report_dir = args
    torch.set_num_threads(1)
    w = WITHHELD[case]
    config = load_config({"model": w.model, "data": {"parametric_error": error, "seed": seed}})
    spec = to_spec(config.model)
    train, held_out = datasets(case, noise, seed, spec)
    started = time.perf_counter()
    report = diagnose(config, data=train, validation=held_out)
    seconds = time.perf_counter() - started
    gap = report.equations[0]
    free = {k: math.inf if v is None else v for k, v in report.measures["free_run"]["held_out"]["nrmse"].items()}  # None: diverged
    row = {"case": case, "noise": noise, "error": error, "seed": seed, "verdict": report.verdict,
           "success": success(case, report.verdict), "seconds": seconds, "free_run": free,
           "exponent": gap.exponent, "win": gap.confidence["win_frequency"]}
    try:
        row["sindy"] = sindy_verdict(spec, nominal_parameters(config, spec), train)
    except ImportError:
        row["sindy"] = None
    row["sindy_success"] = row["sindy"] is not None and success(case, row["sindy"])
    if w.active is not None:
        row["iou"] = _iou(w.active, gap.where, train)
    if report_dir is not None:
        report.save(Path(report_dir) / f"{case}_noise{noise:g}_error{error:g}_seed{seed}")
    return row


def _iou(active, where: dict, train) -> dict:
    """IoU of the flagged state region and of the flagged time windows with the true active samples."""
    s = train.signals
    truth = active(s)
    out = {"region": 0.0, "windows": 0.0}
    if where["flagged_fraction"] > 0:
        r = where["regions"][0]
        v = s[r["signal"]]
        v = v.abs() if r["kind"].startswith("abs") else v
        mask = v > r["value"] if r["kind"].endswith("gt") else v < r["value"]
        out["region"] = float((mask & truth).sum() / (mask | truth).sum())
    if where["time_windows"]:
        t = s["t"]
        mask = torch.zeros_like(truth)
        for win in where["time_windows"]:
            mask |= (t >= win["start"]) & (t <= win["stop"])
        out["windows"] = float((mask & truth).sum() / (mask | truth).sum())
    return out


def localisation_trial(args) -> dict:
    """The localisation alone (no free run, no bootstrap) with a given derivative window."""
    case, noise, seed, window = args
    torch.set_num_threads(1)
    w = WITHHELD[case]
    config = load_config({"model": w.model, "data": {"parametric_error": 0.25, "seed": seed}})
    spec = to_spec(config.model)
    train, held_out = datasets(case, noise, seed, spec, window)
    report = diagnose(config, data=train, validation=held_out, options=DiagnoseOptions(bootstrap=0, free_run=False))
    return {"case": case, "noise": noise, "window": window, **_iou(w.active, report.equations[0].where, train)}


def timing(repeats: int = 3) -> float:
    """Median seconds of a default diagnosis of the MSD (Coulomb) case, N = 2000, on 2 threads."""
    torch.set_num_threads(2)
    case = "msd_coulomb"
    w = WITHHELD[case]
    config = load_config({"model": w.model, "data": {"parametric_error": 0.25, "seed": 0}})
    spec = to_spec(config.model)
    train, held_out = datasets(case, 0.01, 0, spec)
    times = []
    for _ in range(repeats + 1):
        started = time.perf_counter()
        diagnose(config, data=train, validation=held_out)
        times.append(time.perf_counter() - started)
    return statistics.median(times[1:])


def table(rows: list[dict], key: str, noises) -> list[str]:
    kinds = ("in_catalogue", "null", "out_of_catalogue")
    lines = []
    for kind in kinds:
        cells = []
        for noise in noises:
            sel = [r for r in rows if WITHHELD[r["case"]].kind == kind and r["noise"] == noise]
            cells.append(f"{100 * sum(r[key] for r in sel) / max(len(sel), 1):5.1f} % ({len(sel):3d})")
        lines.append(f"{kind:18s} " + "  ".join(cells))
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="2 seeds, parametric error 0.25 only")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cases", nargs="*", default=list(WITHHELD))
    parser.add_argument("--no-timing", action="store_true", help="skip the timing of the default diagnosis")
    parser.add_argument("--errors", type=float, nargs="*", help="parametric error levels (default 0 0.25 0.5)")
    parser.add_argument("--out", default="runs/withheld", help="reports of seed 0 of every case and noise level")
    args = parser.parse_args(argv)
    seeds = range(2 if args.quick else args.seeds)
    errors = tuple(args.errors) if args.errors else (0.25,) if args.quick else PARAMETRIC
    if not args.no_timing:
        print(f"default diagnosis of the MSD case (N = 2000, 16 bootstrap trials, free run included), "
              f"2 threads: {timing():.2f} s (median of 3)", flush=True)
    tasks = [(case, noise, error, seed, args.out if seed == 0 and error == errors[-1] else None)
             for case in args.cases for noise in NOISE for error in errors for seed in seeds]
    rows = []
    started = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        cache = dict(zip(args.cases, pool.map(simulations, args.cases)))
    with ProcessPoolExecutor(args.workers, initializer=_share, initargs=(cache,)) as pool:
        for k, row in enumerate(pool.map(run_trial, tasks, chunksize=1)):
            rows.append(row)
            print(f"[{k + 1}/{len(tasks)}] {row['case']} noise {row['noise']:g} error {row['error']:g} seed {row['seed']}: "
                  f"{row['verdict']} ({'ok' if row['success'] else 'WRONG'}; sindy: {row['sindy']}) "
                  f"{row['seconds']:.2f} s", flush=True)
    print(f"\n{len(rows)} trials in {time.perf_counter() - started:.0f} s")
    print("\nSuccess (top-1 named / null / not explained), by noise:")
    header = " " * 19 + "  ".join(f"noise {100 * n:3.0f} %    " for n in NOISE)
    print(f"{'msam diagnose':40s}   PySINDy discrepancy baseline")
    ours, theirs = table(rows, "success", NOISE), table(rows, "sindy_success", NOISE)
    print(header + "   |   " + header.strip())
    for a, b in zip(ours, theirs):
        print(a + "   |   " + b.split(" ", 1)[1].strip())
    print("\nPer case (ours / PySINDy), all parametric errors:")
    for case in args.cases:
        cells = []
        for noise in NOISE:
            sel = [r for r in rows if r["case"] == case and r["noise"] == noise]
            cells.append(f"{sum(r['success'] for r in sel)}/{len(sel)} vs {sum(r['sindy_success'] for r in sel)}/{len(sel)}")
        print(f"  {case:22s} " + "   ".join(cells))
    print("\nHeld-out free-run NRMSE, in-catalogue cases at <= 1 % noise (median over trials):")
    for case in [c for c in args.cases if WITHHELD[c].kind == "in_catalogue"]:
        sel = [r for r in rows if r["case"] == case and r["noise"] <= 0.01]
        if not sel:
            continue
        med = lambda k: statistics.median(r["free_run"][k] for r in sel)
        ratio = sum(r["free_run"]["start"] >= 5 * r["free_run"]["adapted"] for r in sel)
        below = sum(r["free_run"]["adapted"] < r["free_run"]["retuned"] for r in sel)
        print(f"  {case:22s} start {med('start'):.4f}  retuned {med('retuned'):.4f}  adapted {med('adapted'):.4f}  "
              f"start/adapted >= 5: {ratio}/{len(sel)}  adapted < retuned: {below}/{len(sel)}")
    iou_rows = [r for r in rows if "iou" in r]
    if iou_rows:
        print("\nLocalisation IoU with the true active region (median region / time windows), by noise:")
        for case in sorted({r["case"] for r in iou_rows}):
            for noise in NOISE:
                sel = [r for r in iou_rows if r["case"] == case and r["noise"] == noise]
                if sel:
                    print(f"  {case:22s} noise {100 * noise:3.0f} %: region {statistics.median(r['iou']['region'] for r in sel):.2f}"
                          f"  windows {statistics.median(r['iou']['windows'] for r in sel):.2f}")
        print("  the same cases, localisation only, Savitzky-Golay window 21 samples (1 % of N) instead of the "
              "default 41 (2 %):")
        tasks = [(case, noise, seed, 21) for case in sorted({r["case"] for r in iou_rows}) for noise in NOISE for seed in seeds]
        with ProcessPoolExecutor(args.workers, initializer=_share, initargs=(cache,)) as pool:
            local = list(pool.map(localisation_trial, tasks))
        for case in sorted({r["case"] for r in local}):
            for noise in NOISE:
                sel = [r for r in local if r["case"] == case and r["noise"] == noise]
                print(f"  {case:22s} noise {100 * noise:3.0f} %: region {statistics.median(r['region'] for r in sel):.2f}"
                      f"  windows {statistics.median(r['windows'] for r in sel):.2f}  ({len(sel)} seeds)")
    seconds = [r["seconds"] for r in rows]
    print(f"\nper-trial diagnosis time (1 thread, {args.workers} workers): median {statistics.median(seconds):.2f} s, "
          f"max {max(seconds):.2f} s")
    print(f"reports written under {args.out}/ (seed 0, parametric error {errors[-1]:g}, every case and noise level)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
