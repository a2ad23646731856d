"""Command line: ``msam run CONFIG [--out DIR] [key=value ...]`` and
``msam diagnose CONFIG [--data FILE] [--validate FILE] [--out DIR] [key=value ...]``.

Errors in the user's input print one line naming the place (key, file, column, row, option) and exit
with status 2, without a traceback; a record that tells nothing for a target exits with 3, as does a run
or diagnosis that learnt nothing (its result or report written and saying so); a bug prints one line and
where its traceback is, and exits with 1; Ctrl-C exits with 130. The output folder is checked and locked
before the run; a failed run leaves nothing behind, and a diagnosis replaces its files as one set.
"""
from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import tempfile
import traceback
from pathlib import Path

from msam_torch import __version__
from msam_torch.cli.argtypes import positive, solver
from msam_torch.cli.learnt import require_diagnosis, require_information
from msam_torch.engine.allocator import keep_freed_memory
from msam_torch.errors import ConfigError, Interrupted, MSAMError, NoInformation
from msam_torch.run.progress import LOGGER, logging_to, step

EXIT_BUG = 1
EXIT_INTERRUPTED = 130


def _run(args) -> int:
    from msam_torch.config.schema import dump_config, load_config
    from msam_torch.run.adapt import adapt, candidate_label
    from msam_torch.run.tracking import TensorBoardTracker

    config = load_config(args.config, args.overrides)
    out = Path(args.out)
    tracker = None if args.no_tensorboard else TensorBoardTracker(out / "tensorboard")
    stop = _Stop(args.max_seconds)
    steps = config.adaptation.round_robin_steps + config.adaptation.refinement_steps

    def on_trainer(trainer, equation):
        stop.attach(trainer)
        count = lambda stage, p: step(LOGGER, equation.target, stage, p["iteration"] + 1 + (
            config.adaptation.round_robin_steps if stage == "refinement" else 0), steps)
        trainer.add_callback("round_robin_step", lambda t, **p: p["offset"] or count("round robin", p))
        trainer.add_callback("refinement_step", lambda t, **p: count("refinement", p))
        if tracker is not None:
            tracker.attach(trainer, equation.target, lambda c: candidate_label(equation, c))

    try:
        with stop:
            result = adapt(config, on_trainer=on_trainer, base_dir=Path(args.config).parent)
        if tracker is not None:
            tracker.log_run(result.config, result)
    finally:
        if tracker is not None:
            tracker.close()
    if tracker is not None:
        tracker.save_config(dump_config(config))
    result = stop.record(result)
    path = result.save(out / "result.json")
    require_information(result, path)
    from msam_torch.diagnosis.agreement import stated
    closing = [] if args.no_diagnosis or stop.interrupted else stated(config, result, Path(args.config).parent, path)
    weak = " on the weak form's rows" if result.data.get("form") == "weak" else ""
    for eq in result.equations:
        print(f"starting: {eq.start_equation}")
        print(f"adapted:  {eq.equation}")
        print(f"  sum|eps|{weak} {eq.start['sum_abs_error']:.4g} -> {eq.adapted['sum_abs_error']:.4g}, "
              f"rho {eq.start['rho']:.4f} -> {eq.adapted['rho']:.4f}, {len(eq.ranking)} candidates, {eq.diverged} diverged")
        for stage, label in (("retuned", "retuned starting"), ("adapted_retuned", "retuned adapted")) if eq.theta_tuning else ():
            tuned = eq.theta_tuning[stage]
            off = ", ".join(f"{100 * e:.3g}%" for e in tuned["nominal_error"])
            print(f"{label}: {tuned['equation']}\n  sum|eps| {tuned['sum_abs_error']:.4g}, rho {tuned['rho']:.4f}; "
                  f"nominal theta off by {off}")
        if eq.validation:
            print("  held out, one-step against the estimated derivative: " + ", ".join(
                f"{name} sum|eps| {m['sum_abs_error']:.4g} rho {m['rho']:.4f}" for name, m in eq.validation.items()))
    for group in result.data.get("simulation", []):
        for record, rows in group["free_run_rmse"].items():
            print(f"free-run RMSE of {', '.join(group['outputs'])} on the {record} record: "
                  + " -> ".join(f"{', '.join(f'{v:.4g}' for v in rows[label])} ({label})" for label in rows))
    for line in closing:
        print(line)
    print(f"wrote {path}")
    if stop.interrupted:
        raise Interrupted(f"interrupted (Ctrl-C): the best state found so far is in {path}")
    return 0


class _Stop:
    """Ends the adaptation early, keeping the best state found (Algorithm 1 cut short): after
    ``--max-seconds``, or at the first Ctrl-C while it runs (a second one aborts). The trainers stop
    at their next step; the result records why."""

    def __init__(self, seconds: float | None):
        import time

        self.clock, self.seconds = time.monotonic, seconds
        self.end = None if seconds is None else time.monotonic() + seconds
        self.trainers, self.interrupted, self.timed_out = [], False, False

    def __enter__(self):
        import signal
        import threading

        self.previous = None
        if threading.current_thread() is not threading.main_thread():  # only the main thread handles signals
            return self

        def first_interrupt(signum, frame):
            self.interrupted = True
            signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C aborts
            for trainer in self.trainers:
                trainer.stop_requested = True

        self.previous = signal.signal(signal.SIGINT, first_interrupt)
        return self

    def __exit__(self, *exc):
        import signal

        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)

    def attach(self, trainer) -> None:
        self.trainers.append(trainer)
        self._check(trainer)
        trainer.add_callback("round_robin_step", lambda t, **p: self._check(t))
        trainer.add_callback("refinement_step", lambda t, **p: self._check(t))

    def _check(self, trainer) -> None:
        self.timed_out |= self.end is not None and self.clock() >= self.end
        trainer.stop_requested = self.interrupted or self.timed_out

    def record(self, result):
        if not (self.interrupted or self.timed_out):
            return result
        from dataclasses import replace

        why = {"interrupted": True} if self.interrupted else {"max_seconds": self.seconds}
        if self.timed_out and not self.interrupted:
            print(f"stopped after --max-seconds {self.seconds:g}: the best state found so far is reported", file=sys.stderr)
        return replace(result, data={**result.data, "stopped": why})


def _diagnose(args) -> int:
    from msam_torch.diagnosis.stages.pipeline import diagnose

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    report = diagnose(args.config, data=args.data, validation=args.validate, overrides=args.overrides,
                      options=diagnose_options(args))
    out = Path(args.out)
    LOGGER.info("writing the report to %s", out)
    path = report.save(out, plots=not args.no_plots, tensorboard=not args.no_tensorboard)
    require_diagnosis(report, path)
    print(report)
    print(f"wrote {path}, {out / 'report.md'} and {out / 'report.html'}")
    return 0


DIAGNOSE_OPTIONS = (  # (flag, DiagnoseOptions field, argparse keywords); defaults are DiagnoseOptions'
    ("--half-width", "half_width", {"type": positive(float), "help": "test-function half-width in the data's time "
                                    "units (default: chosen from the band of the measured states)"}),
    ("--bootstrap", "bootstrap", {"type": positive(int, zero=True), "help": "bootstrap trials (0: none; default 16)"}),
    ("--seed", "seed", {"type": int, "help": "seed of the bootstrap trials (default 0)"}),
    ("--solver", "solver", {"type": solver,
                            "help": "torchdiffeq method of the free runs: rk4, midpoint, euler (fixed step) or "
                            "dopri5, bosh3, ... (adaptive); default rk4"}),
    ("--solver-step", "solver_step", {"type": positive(float), "help": "fixed-step solvers: step in time units "
                                      "(default: 1/25 of the band's period, halved until runs at two steps agree)"}),
    ("--rtol", "rtol", {"type": positive(float), "help": "adaptive solvers: relative tolerance (default 1e-6)"}),
    ("--atol", "atol", {"type": positive(float), "help": "adaptive solvers: absolute tolerance relative to each "
                        "state's measured magnitude (default 1e-8)"}),
    ("--max-effects", "max_effects", {"type": positive(int), "help": "effects added in turn, at most: after an "
                                      "accepted effect the rest of the gap is diagnosed again (default 1: no loop)"}),
    ("--quadrature-samples", "quadrature_samples", {"type": positive(int), "help": "records are low-pass filtered and "
                                                    "decimated to about this many samples (default 1000)"}),
)


def diagnose_options(args):
    """The :class:`~msam_torch.diagnosis.DiagnoseOptions` of the ``diagnose`` command line."""
    from msam_torch.diagnosis.options import DiagnoseOptions

    given = {field: getattr(args, field) for _, field, _ in DIAGNOSE_OPTIONS if getattr(args, field) is not None}
    return DiagnoseOptions(**given, free_run=not args.no_free_run)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, run the command, and turn every way it can end into an exit status: 0 done;
    2 bad input (one line naming the place); 3 nothing learnt (a target the record tells nothing for; a run or
    diagnosis that learnt nothing: its files record it); 1 a bug (one line and where its traceback is); 130
    interrupted. A closed stdout ends quietly."""
    try:
        args = _parse(argv)
    except SystemExit as exc:  # --help, --version
        return exc.code or 0
    except MSAMError as exc:
        return _report(exc)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    keep_freed_memory()
    try:
        with logging_to(sys.stderr, args.verbose - args.quiet):
            status = _dispatch(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's final flush
        return status
    except MSAMError as exc:
        return _report(_located(exc, getattr(args, "config", None)))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # stdout closed early (| head): the files are written, the printout is not
        _silence_stdout()
        print("error: standard output was closed before the printout ended (broken pipe); "
              "the files are written", file=sys.stderr)
        return MSAMError.exit_status
    except Exception as exc:
        return _internal_error(exc, args.verbose)


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line naming the option, exit status 2."""

    def error(self, message):
        raise MSAMError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    """The ``msam`` command line: ``run`` and ``diagnose`` with their options."""
    parser = _Parser(prog="msam", description="Model Structure Adaptation Method (MSAM) with PyTorch.")
    parser.add_argument("--version", action="version", version=f"msam-torch {__version__}")
    common = _Parser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0,
                        help="log everything and print the traceback of an internal error")
    common.add_argument("-q", "--quiet", action="count", default=0, help="no progress, warnings and errors only")
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", parents=[common],
                              help="adapt the model of CONFIG to its data and print the adapted equations")
    run.add_argument("config", help="YAML config (see configs/)")
    run.add_argument("overrides", nargs="*", help="config overrides such as adaptation.step_size=one")
    run.add_argument("--out", help="output folder (default: a new runs/<config name>/version_N)")
    run.add_argument("--no-tensorboard", action="store_true", help="do not write TensorBoard event files")
    run.add_argument("--no-diagnosis", action="store_true", help="on measured data, do not diagnose the same "
                     "record to state whether the diagnosis reads the same law")
    run.add_argument("--max-seconds", type=_seconds, help="stop the adaptation after this many seconds, keeping "
                                                            "the best state found (result.json records it)")
    run.set_defaults(handler=_run, out_default="{stem}")
    diag = commands.add_parser("diagnose", parents=[common], help="say where the starting model of CONFIG misses "
                               "its data, which unmodelled effect causes it and how far adding it shrinks the gap")
    diag.add_argument("config", help="YAML config (its 'model' is the starting model)")
    diag.add_argument("overrides", nargs="*", help="config overrides such as data.noise=0.01")
    diag.add_argument("--data", help="measured CSV/Parquet file (default: the config's data)")
    diag.add_argument("--validate", help="held-out CSV/Parquet file, ideally from another excitation")
    diag.add_argument("--out", help="output folder (default: a new runs/<config name>_diagnosis/version_N)")
    diag.add_argument("--threads", type=positive(int), help="torch CPU threads (1 is fastest on a busy machine)")
    for flag, field, keywords in DIAGNOSE_OPTIONS:
        diag.add_argument(flag, dest=field, **keywords)
    diag.add_argument("--no-free-run", action="store_true", help="do not simulate the models (no free-run measures)")
    diag.add_argument("--no-plots", action="store_true", help="write the report without its figures")
    diag.add_argument("--no-tensorboard", action="store_true", help="do not write TensorBoard event files")
    diag.set_defaults(handler=_diagnose, out_default="{stem}_diagnosis")
    return parser


def _parse(argv) -> argparse.Namespace:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)  # overrides may follow options
    unknown = [e for e in extra if e.startswith("-") or "=" not in e]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    if extra:
        args.overrides = list(getattr(args, "overrides", [])) + extra
    if args.out is None:  # a new folder per run: runs/<stem>/version_N
        from msam_torch.run.outputs import new_version

        args.out = str(new_version(Path("runs") / args.out_default.format(stem=Path(args.config).stem)))
    return args


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number of seconds")
    return value


def _dispatch(args) -> int:
    """Run the command with its output folder checked and locked; a failed run that created the
    folder removes it (a run that learnt nothing keeps the result that says so)."""
    from msam_torch.run.outputs import check_folder, locked

    belongs = None
    if args.command == "diagnose":
        from msam_torch.diagnosis.report.gap_report import is_report_file as belongs
    out = check_folder(args.out, "--out", belongs)
    created = not out.exists()
    with locked(out):
        try:
            return args.handler(args)
        except BaseException as exc:
            if created and not isinstance(exc, (NoInformation, Interrupted, BrokenPipeError)):
                shutil.rmtree(out, ignore_errors=True)
            raise


def _located(exc: MSAMError, config: str | None) -> MSAMError:
    """A config error found past validation (an expression, a target, a term, a data setting the
    record needs) with the config file it is in, where the message does not name one."""
    if config is None or not isinstance(exc, ConfigError) or "(in " in str(exc) \
            or "(command-line override " in str(exc) or not exc.key.startswith(("model.", "data.")):
        return exc
    located = ConfigError("", f"{exc} (in {config})")
    located.key = exc.key
    return located


def _report(exc: MSAMError) -> int:
    print(f"error: {_one_line(exc)}", file=sys.stderr)
    return exc.exit_status


def _internal_error(exc: Exception, verbose: bool) -> int:
    """One line naming the bug and where its traceback is (a temporary log, or stderr with -v)."""
    where = "traceback above"
    if not verbose:
        try:
            fd, log = tempfile.mkstemp(prefix="msam-error-", suffix=".log")
            with os.fdopen(fd, "w") as handle:
                traceback.print_exc(file=handle)
            where = f"traceback in {log}; rerun with -v to print it"
        except OSError:  # no writable temporary folder: the traceback goes to stderr
            verbose = True
    if verbose:
        traceback.print_exc()
    print(f"internal error (a bug in msam-torch, please report it): {type(exc).__name__}: {_one_line(exc)} "
          f"({where})", file=sys.stderr)
    return EXIT_BUG


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":
    sys.exit(main())
