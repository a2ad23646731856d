"""Shared machinery of the reproduction experiments: YAML experiment configs, a resumable store
of finished trials, and the writers of CSV, Markdown, PNG and TensorBoard outputs.

A run writes one JSON file per finished trial under ``<out>/trials/<variant>/`` (atomically), and
skips the trials whose file exists, so an interrupted run resumes where it stopped and ends with
the same table. Trials of one variant are run in batches of ``batch_trials`` as one tensor program.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Callable, Optional, Union

from pydantic import BaseModel, ConfigDict, Field

from msam_torch.config.schema import Config, dump_config, load_config, read_yaml, validate
from msam_torch.run.result import _finite, write_atomic
from msam_torch.run.trials import MAX_ELEMENTS, Trial, TrialResult, run_trials

ROOT = Path(__file__).resolve().parent.parent


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class EquationSettings(_Strict):
    """Per state equation: Algorithm 1 iterations and the true adjustments (null: any)."""

    round_robin_steps: Optional[int] = Field(None, ge=1)
    refinement_steps: Optional[int] = Field(None, ge=0)
    truth: Optional[list[Optional[str]]] = None


class ExperimentConfig(_Strict):
    """An experiment over parametric error levels and trials (Tables 2-4, Figure 5)."""

    title: str
    model: str = Field(description="model/data/adaptation config, relative to this file")
    overrides: list[str] = Field([], description="key=value overrides of the model config for every variant")
    levels: list[float] = Field(min_length=1, description="parametric error levels, as fractions")
    trials: int = Field(ge=1)
    seed: int = 0
    batch_trials: int = Field(1000, ge=1, description="trials per tensor program")
    max_elements: int = Field(MAX_ELEMENTS, ge=1, description="values per (T, C, N, Q) chunk")
    equations: dict[str, EquationSettings] = {}
    variants: dict[str, list[str]] = Field(min_length=1, description="name -> key=value overrides")
    labels: dict[str, str] = {}
    paper: dict = Field({}, description="the paper's figures, shown beside ours")


def load_experiment(path: Union[str, Path]) -> ExperimentConfig:
    return validate(ExperimentConfig, read_yaml(path, "experiment config"), str(path))


def model_path(experiment: ExperimentConfig, config_path: Path) -> Path:
    """The model config an experiment config names (relative to the experiment config's folder);
    its folder is the base of the data paths the model config names, as for ``msam run``."""
    return Path(config_path).parent / experiment.model


def model_config(experiment: ExperimentConfig, config_path: Path, variant: str) -> Config:
    """The model config of ``variant``: the experiment's overrides, then the variant's."""
    return load_config(model_path(experiment, config_path), experiment.overrides + experiment.variants[variant])


def level_name(level: float) -> str:
    return f"{round(level * 100):03d}"


class Store:
    """One JSON file per finished trial: ``<root>/trials/<variant>/<level %>/<index>.json``."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def path(self, variant: str, trial: Trial) -> Path:
        return self.root / "trials" / variant / level_name(trial.level) / f"{trial.index:04d}.json"

    def has(self, variant: str, trial: Trial) -> bool:
        return self.path(variant, trial).exists()

    def save(self, variant: str, trial: Trial, record: dict) -> None:
        write_atomic(self.path(variant, trial), json.dumps(_finite(record), indent=1))

    def load(self, variant: str, trial: Trial) -> dict:
        return json.loads(self.path(variant, trial).read_text())


def all_trials(experiment: ExperimentConfig) -> list[Trial]:
    return [Trial(level, i) for level in experiment.levels for i in range(experiment.trials)]


def trial_record(result: TrialResult, experiment: ExperimentConfig) -> dict:
    """A finished trial as JSON: parameters, and per equation the outcome and its success."""
    equations = []
    for eq in result.equations:
        truth = experiment.equations.get(eq.target, EquationSettings()).truth
        chosen = [a for a in eq.adjustments if a is not None]
        success = None if truth is None else all(t is None or t == a for t, a in zip(truth, chosen))
        record = eq.to_dict()
        record["ranking"] = record["ranking"][:8]  # the best few; the full ranking is in a run's result.json
        equations.append({**record, "success": success})
    return {"level": result.trial.level, "index": result.trial.index, "parameters": result.parameters,
            "equations": equations}


Compute = Callable[[Config, list[Trial]], list[dict]]


def standard_compute(experiment: ExperimentConfig, config_path: Path) -> Compute:
    """Run Algorithm 1 on a batch of trials (one tensor program per state equation)."""
    settings = {k: {n: v for n, v in s.model_dump().items() if n != "truth" and v is not None}
                for k, s in experiment.equations.items()}

    def compute(config: Config, trials: list[Trial]) -> list[dict]:
        results = run_trials(config, trials, experiment.seed, model_path(experiment, config_path).parent, settings,
                             max_elements=experiment.max_elements)
        return [trial_record(r, experiment) for r in results]

    return compute


def run_protocol(experiment: ExperimentConfig, config_path: Path, out: Path, compute: Compute | None = None,
                 max_trials: int | None = None, log=print) -> dict | None:
    """Compute the missing trials of every variant; return ``{variant: [record, ...]}`` when all
    are done, or None when ``max_trials`` stopped the run early (the next run resumes)."""
    store = Store(out)
    compute = compute or standard_compute(experiment, config_path)
    budget = math.inf if max_trials is None else max_trials
    timings = {}
    for variant in experiment.variants:
        config = model_config(experiment, config_path, variant)
        pending = [t for t in all_trials(experiment) if not store.has(variant, t)]
        started = time.perf_counter()
        while pending and budget > 0:
            batch = pending[: int(min(experiment.batch_trials, budget))]
            pending = pending[len(batch):]
            for trial, record in zip(batch, compute(config, batch)):
                store.save(variant, trial, record)
            budget -= len(batch)
            log(f"{variant}: {len(batch)} trials done, {len(pending)} to go")
        timings[variant] = time.perf_counter() - started
        if pending:
            return None
    log("wall time per variant (this run): " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    return {v: [store.load(v, t) for t in all_trials(experiment)] for v in experiment.variants}


def mean_std(values: list[float]) -> str:
    values = [v for v in values if v is not None and math.isfinite(v)]
    if not values:
        return "n/a"
    if len(values) == 1 or max(values) == min(values):
        return f"{values[0]:.4g}"
    return f"{statistics.fmean(values):.4g} ± {statistics.stdev(values):.2g}"


def markdown_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def protocol_notes(config: Config, experiment: ExperimentConfig | None = None) -> str:
    """The protocol choices of docs/design.md section 2 that this output used."""
    a, d = config.adaptation, config.data
    step = {"dm": "literal dM-scaled step added to gamma (Eq. 16-18, design 2.1)",
            "gauss_newton": "plain Gauss-Newton step in exponent units (design 2.1 option)"}[a.scaling]
    mu = {"eq20": "mu = corr(eps, Phi dGamma) (Eq. 20)", "one": "mu = 1",
          "line_search": "backtracking line search on the fitness"}[a.step_size]
    theta = {"fixed": "theta fixed at the nominal values", "varpro": "theta re-solved every step (variable "
             "projection, Kaufman Jacobian, design 3)"}[a.theta]
    lines = [
        f"- step: {step}; {mu}; {theta}; adjustment functions normalised: {a.normalize}",
        f"- dgamma = {a.dgamma} (design 2.4); dM denominator over the adjustable components only (design 2.2)",
        "- adjustment sign: |f|^gamma for abs(...) functions, sign(f)|f|^gamma otherwise; 'starting' figures "
        "from the unadjusted model (design 2.5)",
        f"- float64, |f| floored at 1e-12, rank-tolerant least squares, gamma limit {a.gamma_limit} (design 2.6)",
        f"- data: {d.system or d.file}, derivatives {d.derivatives}, noise {d.noise} (design 2.9 excitations)",
    ]
    if experiment is not None:
        lines.append(f"- parametric error: physical parameters perturbed with total relative error = level, split at "
                     f"random (flat Dirichlet), random signs, none below 5 % of its true value "
                     f"(msam_torch.data.systems.perturb_parameters, design 2.8); {experiment.trials} trials per level, "
                     f"seed {experiment.seed}")
    return "\n".join(lines)


def write_text(out: Path, name: str, text: str) -> Path:
    return write_atomic(out / name, text)


def write_csv(out: Path, name: str, frame) -> Path:
    return write_atomic(out / name, frame.to_csv(index=False))


def save_figure(fig, path: Path) -> Path:
    """Save a matplotlib figure atomically (temporary file, then rename)."""
    import os
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def tensorboard_scalars(out: Path, run: str, scalars: dict[str, list[tuple[float, float]]], config_text: str = "") -> None:
    """Write ``{tag: [(step, value), ...]}`` as one TensorBoard run under ``<out>/tensorboard/<run>``."""
    from torch.utils.tensorboard import SummaryWriter

    log_dir = out / "tensorboard" / run
    writer = SummaryWriter(str(log_dir))
    for tag, points in scalars.items():
        for step, value in points:
            if value is not None and math.isfinite(value):
                writer.add_scalar(tag, value, step)
    writer.flush()
    writer.close()
    if config_text:
        write_atomic(log_dir / "config.yaml", config_text)


def arguments(default_config: str, default_out: str, description: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("config", nargs="?", default=str(ROOT / default_config), help="experiment YAML")
    parser.add_argument("--out", default=str(ROOT / default_out), help="output folder")
    parser.add_argument("--max-trials", type=int, default=None,
                        help="compute at most this many new trials, then stop (the next run resumes)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (see README, Performance)")
    args = parser.parse_args()
    set_threads(args.threads)
    return args


def set_threads(threads: int) -> None:
    """Intra-op threads: the chunks are cache-sized, so one thread per process is fastest on a
    shared machine (OpenMP threads spin-wait when the cores are oversubscribed)."""
    import torch

    torch.set_num_threads(threads)


def main_guard(fn) -> None:
    """Run ``fn`` (with the allocator setting of msam_torch.engine.allocator) and turn input errors into
    one line and exit status 2."""
    from msam_torch.engine.allocator import keep_freed_memory
    from msam_torch.errors import MSAMError

    keep_freed_memory()
    try:
        sys.exit(fn())
    except MSAMError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)


__all__ = ["ExperimentConfig", "Store", "run_protocol", "load_experiment", "model_config", "protocol_notes",
           "markdown_table", "mean_std", "write_text", "write_csv", "save_figure", "tensorboard_scalars",
           "arguments", "main_guard", "dump_config", "level_name"]


def median_model(records: list[dict], equation, position: int) -> str:
    """The most frequent selection among ``records`` with the median exponent of each component."""
    from collections import Counter

    from msam_torch.model.notation import format_component

    picks = [tuple(r["equations"][position]["adjustments"]) for r in records]
    common, count = Counter(picks).most_common(1)[0]
    chosen = [r["equations"][position] for r in records if tuple(r["equations"][position]["adjustments"]) == common]
    texts = [f.text for f in equation.adjustments]
    terms = []
    for i, adjustment in enumerate(common):
        if adjustment is None:
            terms.append(format_component(equation, i, None, None))
        else:
            gamma = statistics.median(e["exponents"][i] for e in chosen)
            terms.append(format_component(equation, i, texts.index(adjustment), gamma))
    return f"{equation.target} ~ " + " + ".join(f"θ{i + 1} {t}" for i, t in enumerate(terms)) + f" ({count}/{len(records)})"


def summary_rows(records: list[dict], levels: list[float], equation, position: int) -> list[dict]:
    """Per level: starting and adapted sum|eps| and rho (mean ± std), success rate, median model."""
    rows = []
    for level in levels:
        cell = [r for r in records if r["level"] == level]
        eqs = [r["equations"][position] for r in cell]
        success = [e["success"] for e in eqs if e["success"] is not None]
        rows.append({
            "target": equation.target, "level": level, "trials": len(cell),
            "start_sum_abs_error": mean_std([e["start"]["sum_abs_error"] for e in eqs]),
            "start_rho": mean_std([e["start"]["rho"] for e in eqs]),
            "adapted_sum_abs_error": mean_std([e["adapted"]["sum_abs_error"] for e in eqs]),
            "adapted_rho": mean_std([e["adapted"]["rho"] for e in eqs]),
            "success": sum(success) / len(success) if success else None,
            "median_adapted_model": median_model(cell, equation, position),
        })
    return rows
