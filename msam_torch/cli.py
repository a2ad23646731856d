"""Command line: ``msam run CONFIG [--out DIR] [key=value ...]`` and
``msam diagnose CONFIG [--data FILE] [--validate FILE] [--out DIR] [key=value ...]``.

Errors in the user's input print one line naming the place (key, file, column, row) and exit
with status 2, without a traceback. Nothing is written unless the run succeeds.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from . import __version__
from .allocator import keep_freed_memory
from .errors import MSAMError

EXIT_INPUT_ERROR = 2


def _run(args) -> int:
    from tqdm.auto import tqdm

    from .api import adapt, candidate_label
    from .config import dump_config, load_config
    from .tracking import TensorBoardTracker

    config = load_config(args.config, args.overrides)
    out = Path(args.out or Path("runs") / Path(args.config).stem)
    tracker = None if args.no_tensorboard else TensorBoardTracker(out / "tensorboard")
    bars = []

    def on_trainer(trainer, equation):
        bar = tqdm(desc=equation.target, unit="step", disable=args.quiet or not sys.stderr.isatty(), leave=False)
        bars.append(bar)
        trainer.add_callback("round_robin_step", lambda t, **p: bar.update(1))
        trainer.add_callback("refinement_step", lambda t, **p: bar.update(1))
        if tracker is not None:
            tracker.attach(trainer, equation.target, lambda c: ", ".join(candidate_label(equation, c)))

    try:
        result = adapt(config, on_trainer=on_trainer, base_dir=Path(args.config).parent)
    finally:
        for bar in bars:
            bar.close()
        if tracker is not None:
            tracker.close()
    if tracker is not None:
        tracker.save_config(dump_config(config))
    path = result.save(out / "result.json")
    for eq in result.equations:
        print(f"starting: {eq.start_equation}")
        print(f"adapted:  {eq.equation}")
        print(f"  sum|eps| {eq.start['sum_abs_error']:.4g} -> {eq.final['sum_abs_error']:.4g}, "
              f"rho {eq.start['rho']:.4f} -> {eq.final['rho']:.4f}, "
              f"{len(eq.ranking)} candidates, {eq.diverged} diverged")
        for stage, label in (("start", "tuned starting"), ("final", "tuned adapted")) if eq.theta_tuning else ():
            tuned = eq.theta_tuning[stage]
            off = ", ".join(f"{100 * e:.3g}%" for e in tuned["nominal_error"])
            print(f"{label}: {tuned['equation']}\n  sum|eps| {tuned['sum_abs_error']:.4g}, rho {tuned['rho']:.4f}; "
                  f"nominal theta off by {off}")
        if eq.validation:
            print("  held out: " + ", ".join(f"{name} sum|eps| {m['sum_abs_error']:.4g} rho {m['rho']:.4f}"
                                             for name, m in eq.validation.items()))
    for group in result.data.get("simulation", []):
        for record, rows in group["free_run_rmse"].items():
            print(f"free-run RMSE of {', '.join(group['outputs'])} on the {record} record: "
                  + " -> ".join(f"{', '.join(f'{v:.4g}' for v in rows[label])} ({label})" for label in rows))
    print(f"wrote {path}")
    return 0


def _diagnose(args) -> int:
    from .diagnose import diagnose

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    report = diagnose(args.config, data=args.data, validation=args.validate, overrides=args.overrides,
                      options=diagnose_options(args))
    out = Path(args.out or Path("runs") / f"{Path(args.config).stem}_diagnosis")
    path = report.save(out, plots=not args.no_plots)
    print(report)
    print(f"wrote {path} and {out / 'report.md'}")
    return 0


def _positive(kind):
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value
    return parse


DIAGNOSE_OPTIONS = (  # (flag, DiagnoseOptions field, argparse keywords); defaults are DiagnoseOptions'
    ("--half-width", "half_width", {"type": _positive(float), "help": "test-function half-width in the data's time "
                                    "units (default: chosen from the band of the measured states)"}),
    ("--bootstrap", "bootstrap", {"type": int, "help": "bootstrap trials (0: none; default 16)"}),
    ("--seed", "seed", {"type": int, "help": "seed of the bootstrap trials (default 0)"}),
    ("--solver", "solver", {"help": "torchdiffeq method of the free runs: rk4, midpoint, euler (fixed step) or "
                            "dopri5, bosh3, ... (adaptive); default rk4"}),
    ("--solver-step", "solver_step", {"type": _positive(float), "help": "fixed-step solvers: step in time units "
                                      "(default: halved from 1/500 of the record until runs at two steps agree)"}),
    ("--rtol", "rtol", {"type": _positive(float), "help": "adaptive solvers: relative tolerance (default 1e-6)"}),
    ("--atol", "atol", {"type": _positive(float), "help": "adaptive solvers: absolute tolerance relative to each "
                        "state's measured magnitude (default 1e-8)"}),
    ("--quadrature-samples", "quadrature_samples", {"type": _positive(int), "help": "records are low-pass filtered and "
                                                    "decimated to about this many samples (default 1000)"}),
)


def diagnose_options(args):
    """The :class:`~msam_torch.diagnose.DiagnoseOptions` of the ``diagnose`` command line."""
    from .diagnose import DiagnoseOptions

    given = {field: getattr(args, field) for _, field, _ in DIAGNOSE_OPTIONS if getattr(args, field) is not None}
    return DiagnoseOptions(**given, free_run=not args.no_free_run)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msam", description="Model Structure Adaptation Method (MSAM) with PyTorch.")
    parser.add_argument("--version", action="version", version=f"msam-torch {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="adapt the model of CONFIG to its data and print the adapted equations")
    run.add_argument("config", help="YAML config (see configs/)")
    run.add_argument("overrides", nargs="*", help="config overrides such as adaptation.step_size=one")
    run.add_argument("--out", help="output folder (default runs/<config name>)")
    run.add_argument("--no-tensorboard", action="store_true", help="do not write TensorBoard event files")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(handler=_run)
    diag = commands.add_parser("diagnose", help="say where the starting model of CONFIG misses its data, which "
                               "unmodelled effect causes it and how far adding it shrinks the gap")
    diag.add_argument("config", help="YAML config (its 'model' is the starting model)")
    diag.add_argument("overrides", nargs="*", help="config overrides such as data.noise=0.01")
    diag.add_argument("--data", help="measured CSV/Parquet file (default: the config's data)")
    diag.add_argument("--validate", help="held-out CSV/Parquet file, ideally from another excitation")
    diag.add_argument("--out", help="output folder (default runs/<config name>_diagnosis)")
    diag.add_argument("--threads", type=int, help="torch CPU threads (1 is fastest on a busy machine)")
    for flag, field, keywords in DIAGNOSE_OPTIONS:
        diag.add_argument(flag, dest=field, **keywords)
    diag.add_argument("--no-free-run", action="store_true", help="do not simulate the models (no free-run measures)")
    diag.add_argument("--no-plots", action="store_true", help="write gap_report.json and report.md without PNG plots")
    diag.set_defaults(handler=_diagnose)
    args, extra = parser.parse_known_args(argv)  # overrides may follow options
    unknown = [e for e in extra if e.startswith("-") or "=" not in e]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    if extra:
        args.overrides = list(getattr(args, "overrides", [])) + extra
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    keep_freed_memory()
    try:
        return args.handler(args)
    except MSAMError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INPUT_ERROR


if __name__ == "__main__":
    sys.exit(main())
