"""``diagnose(config, data, validation) -> GapReport``: where the gap lies, which effect causes it,
how far it shrinks.

Each state equation is diagnosed in stages (:mod:`.equation`); then the starting, theta-retuned
and adapted models are compared one-step and in free run (:mod:`msam_torch.diagnosis.compare.comparison`) and the equations'
verdicts make the report's (:mod:`msam_torch.diagnosis.compare.verdict`). A config evaluated by simulation is diagnosed by
:mod:`.simulated`. Accepted effects are added to the model and what remains is diagnosed again,
effect after effect (:mod:`msam_torch.diagnosis.effects.multi`).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import torch

from msam_torch.config.schema import Config, load_config
from msam_torch.data.loading import DataArgument, resolve_datasets
from msam_torch.diagnosis.compare.comparison import check_solver, compare
from msam_torch.diagnosis.compare.verdict import demoted, overall
from msam_torch.diagnosis.effects.adapted import with_effects
from msam_torch.diagnosis.effects.multi import in_turn
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.report.gap_report import GapReport
from msam_torch.diagnosis.stages.equation import diagnose_equation
from msam_torch.diagnosis.stages.simulated import diagnose_simulated
from msam_torch.run.adapt import nominal_parameters
from msam_torch.run.estimation import choose
from msam_torch.run.plan import prepare
from msam_torch.run.progress import LOGGER, step, tracked


def diagnose(config: Config | dict | str | Path, data: DataArgument = None, validation: DataArgument = None,
             overrides: list[str] = (), options: DiagnoseOptions = DiagnoseOptions(),
             base_dir: str | Path | None = None) -> GapReport:
    """Diagnose the gap between the starting model of ``config`` and measured data.

    ``data``: the training record, as for :func:`msam_torch.run.adapt.adapt` (a CSV/Parquet path, a
    pandas DataFrame or a mapping of column to array read through the config's ``data`` section,
    or a :class:`~msam_torch.data.loading.Dataset`); default: the config's own data. ``validation``:
    held-out data in the same forms (default: the config's validation range or file; without
    any, alternate time blocks of the training record are held out). Paths in the config are
    relative to ``base_dir`` (default: the config file's folder). With ``options.max_effects``
    above 1, effects are added in turn, at most that many (:func:`~msam_torch.diagnosis.effects.multi.in_turn`).
    """
    check_solver(options.solver)
    if base_dir is None:
        base_dir = Path(config).parent if isinstance(config, (str, Path)) else Path(".")
    if not isinstance(config, Config):
        config = load_config(config, overrides)
    once = lambda c: _diagnose_once(c, data, validation, options, Path(base_dir))
    return once(config)[0] if options.max_effects == 1 else in_turn(config, once, options.max_effects)


def _diagnose_once(config: Config, data: DataArgument, validation: DataArgument, options: DiagnoseOptions,
                   base_dir: Path) -> tuple[GapReport, Callable | None]:
    """One diagnosis of ``config``'s starting model, and a function giving the config with the
    effects of the equations it is given added (None when evaluated by simulation)."""
    plan = prepare(config, in_memory=data is not None)
    if plan.simulates:
        return diagnose_simulated(plan, base_dir, options, data=data, validation=validation), None
    spec, device = plan.spec, plan.device
    _warn_repeated_terms(spec)
    total = len(spec.equations) + 2  # reading the data, each equation, comparing the models
    step(LOGGER, "diagnose", "reading the data", 0, total)
    train, held_out = resolve_datasets(config.data, spec, base_dir, plan.dtype, data, validation, plan.derivatives)
    train, held_out = (None if d is None else replace(d, signals={k: v.to(device) for k, v in d.signals.items()})
                       for d in (train, held_out))
    started = time.perf_counter()  # the diagnosis itself, data loading excluded
    parameters = nominal_parameters(config, spec)
    generator = torch.Generator().manual_seed(options.seed)
    estimation = choose(spec, config.data, train, held_out, plan.derivatives, options.half_width,
                        options.quadrature_samples, refine=True)
    equations = [diagnose_equation(spec, equation, train, estimation, parameters, options, generator)
                 for equation in tracked(spec.equations, LOGGER, "diagnose", lambda e: f"equation {e.target}", total, 1)]
    gaps = tuple(e.gap for e in equations)
    series = {e.gap.target: e.series for e in equations}
    step(LOGGER, "diagnose", "comparing the models", total - 1, total)
    gap_measures = compare(spec, [e.model for e in equations], train, held_out, series, options,
                           estimation.info["band_edge"], {"train": estimation.train, "held_out": estimation.held_out},
                           {label: estimation.held_inputs(label) for label in ("train", "held_out")})
    kind, verdict, reasons = overall(gaps, any(g.significant for g in gaps), name_targets=len(gaps) > 1,
                                     free_run=gap_measures.get("free_run"))
    gaps = demoted(gaps, kind, reasons)
    data_info = {"train": dict(train.info),
                 "held_out": dict(held_out.info) if held_out is not None else "alternate time blocks",
                 "nominal_parameters": parameters}
    report = GapReport(verdict_kind=kind, verdict=verdict, equations=gaps, measures=gap_measures, data=data_info,
                       options=asdict(options), config=config.model_dump(mode="json"),
                       seconds=time.perf_counter() - started, reasons=tuple(reasons), series=series,
                       models=tuple(e.model for e in equations))
    models = {e.gap.target: e.model for e in equations}
    return report, lambda targets: with_effects(config, spec.equations, {t: models[t] for t in targets})


def _warn_repeated_terms(spec) -> None:
    """A warning per equation whose components read the same term: a re-fit identifies only the
    sum of their theta (and splits it evenly); the diagnosis makes its own copies of a component."""
    for equation in spec.equations:
        seen: dict[str, list[int]] = {}
        for i, component in enumerate(equation.components):
            seen.setdefault(component.term.text, []).append(i + 1)
        for term, where in seen.items():
            if len(where) > 1:
                LOGGER.warning("%s: components %s read the same term %s: the data identify only the sum of their "
                               "theta (a re-fit splits it evenly); one component is enough, the diagnosis tries "
                               "copies of it itself", equation.target, " and ".join(map(str, where)), term)
