"""Measurement noise and parametric error on a controlled case, each protocol as one batch.

Table 1 (noise): the true system is simulated, only its sensor signals are kept (the harmonic
oscillator: displacement x and force u), noise of ``level x std(signal)`` is added with one seed per
trial, the unmeasured states and derivatives are estimated (``data.derivatives``, default:
Savitzky-Golay with the noise-floor window rule) and MSAM runs with the nominal parameters.
Table 2 (parametric error): exact signals, nominal parameters perturbed by
``systems.perturb_parameters`` (total relative error = level, one generator seed per trial), run
with every theta mode listed. A trial succeeds when the selected adjustments equal the expected
form. All trials of a row run as one batch on the trials axis T.

    python -m experiments.suites.noise_robustness   # both tables, harmonic
    python -m experiments.suites.noise_robustness --config configs/vanderpol.yaml \\
        --expect "abs(x),*,*" --noise 0 0.001 0.01 --errors none --set data.derivatives=loess
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from experiments.common import main_guard
from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import load_datasets
from msam_torch.data.systems import perturb_parameters
from msam_torch.run.adapt import adapt_equation

THETA_MODES = {
    "fixed": [],
    "tune_theta": ["adaptation.tune_theta=true"],
    "varpro": ["adaptation.theta=varpro"],
    "varpro+rms": ["adaptation.theta=varpro", "adaptation.normalize=rms"],
}


def success(result, expect: list[str]) -> bool:
    chosen = [a for a in result.adjustments if a is not None]
    return len(chosen) == len(expect) and all(e == "*" or e == c for e, c in zip(expect, chosen))


def summary(results, expect) -> dict:
    ok = [success(r, expect) for r in results]
    gammas = np.array([[g for g in r.exponents if g is not None] for r, good in zip(results, ok) if good])
    return {"success": float(np.mean(ok)), "trials": len(ok),
            "gamma_mean": gammas.mean(0).tolist() if gammas.size else None,
            "gamma_std": gammas.std(0).tolist() if gammas.size else None}


def noise_table(config_path: str, overrides: list[str], levels: list[float], seeds: int, expect: list[str]) -> list[dict]:
    rows = []
    for level in levels:
        config = load_config(config_path, ["data.derivatives=auto"] + overrides + [f"data.noise={level}",
                                                                                   "data.parametric_error=0"])
        spec = to_spec(config.model)
        datasets = [load_datasets(config.data.model_copy(update={"seed": s}), spec)[0] for s in range(seeds)]
        signals = {k: torch.stack([d.signals[k] for d in datasets]) for k in datasets[0].signals}
        started = time.perf_counter()
        results = [r for eq in spec.equations for r in adapt_equation(config, eq, signals, spec.theta(eq))]
        windows = sorted({e["window"] for d in datasets if isinstance(d.info["derivatives"], dict)
                          for e in d.info["derivatives"].values() if e["window"] is not None})
        method = {e["method"] for d in datasets if isinstance(d.info["derivatives"], dict)
                  for e in d.info["derivatives"].values()} or {datasets[0].info["derivatives"]}
        rows.append({"noise": level, **summary(results, expect), "estimator": ",".join(sorted(method)),
                     "windows": windows, "seconds": time.perf_counter() - started})
    return rows


def error_table(config_path: str, overrides: list[str], levels: list[float], trials: int, expect: list[str],
                modes: list[str]) -> list[dict]:
    rows = []
    for mode in modes:
        for level in levels:
            config = load_config(config_path, overrides + THETA_MODES[mode] + ["data.noise=0", "data.parametric_error=0"])
            spec = to_spec(config.model)
            signals = load_datasets(config.data, spec)[0].signals
            draws = [perturb_parameters(spec.parameters, level, torch.Generator().manual_seed(s)) for s in range(trials)]
            started = time.perf_counter()
            results = []
            for eq in spec.equations:
                theta = torch.stack([spec.theta(eq, p) for p in draws])
                results += adapt_equation(config, eq, signals, theta)
            revealed = np.mean([np.mean(r.theta_tuning["adapted_retuned"]["nominal_error"]) for r in results])
            rows.append({"theta": mode, "parametric_error": level, **summary(results, expect),
                         "mean_revealed_theta_error": float(revealed), "seconds": time.perf_counter() - started})
    return rows


def print_table(rows: list[dict], columns: list[str]) -> None:
    def cell(value):
        if isinstance(value, float):
            return f"{value:.4g}"
        if isinstance(value, list):
            return "[" + ", ".join(cell(v) for v in value) + "]"
        return str(value)

    cells = [[cell(r[c]) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(columns)]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths)))
    for row in cells:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="configs/harmonic.yaml")
    parser.add_argument("--expect", default="abs(x_dot),abs(x)",
                        help="expected adjustment per adjustable component, comma separated; '*' matches any")
    parser.add_argument("--noise", type=float, nargs="*", default=[0.0, 0.001, 0.01, 0.02])
    parser.add_argument("--seeds", type=int, default=20, help="noise seeds per level")
    parser.add_argument("--errors", nargs="*", default=["0", "0.5", "1", "2"], help="parametric error levels or 'none'")
    parser.add_argument("--trials", type=int, default=50, help="parametric-error trials per level")
    parser.add_argument("--modes", nargs="*", default=list(THETA_MODES), choices=list(THETA_MODES))
    parser.add_argument("--json", help="also write the rows to this JSON file")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="config override such as data.derivatives=loess (repeatable)")
    args = parser.parse_args()
    expect = args.expect.split(",")
    out = {}
    if args.noise:
        print(f"Table 1: measurement noise ({args.config}, {args.seeds} seeds per level, 0 % parametric error)")
        out["noise"] = noise_table(args.config, args.overrides, args.noise, args.seeds, expect)
        print_table(out["noise"], ["noise", "success", "trials", "estimator", "windows", "gamma_mean", "gamma_std", "seconds"])
    if args.errors and args.errors != ["none"]:
        print(f"\nTable 2: parametric error ({args.config}, exact signals, {args.trials} trials per level)")
        out["parametric_error"] = error_table(args.config, args.overrides, [float(e) for e in args.errors],
                                              args.trials, expect, args.modes)
        print_table(out["parametric_error"], ["theta", "parametric_error", "success", "trials", "gamma_mean",
                                              "mean_revealed_theta_error", "seconds"])
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main_guard(main)
