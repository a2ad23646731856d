"""The diagnosis of a model judged by simulation (``adaptation.evaluation: simulation``), for
records whose states are not all measured (the paper's section 2 alternative).

Which: Algorithm 1 runs on the simulated outputs (:func:`msam_torch.run.adapt.adapt`); each adjusted
component is named from the catalogue (:mod:`msam_torch.diagnosis.catalogue.entries`). How far: free runs of the starting,
theta-retuned and adapted models on the training and held-out records; the null rule
(:mod:`msam_torch.diagnosis.compare.confidence`) on the held-out free-run RMSE says whether the adaptation is significant;
without a significant one, "no significant gap" needs the re-fitted start's held-out free-run
residual to look like measurement noise (:func:`.structure.whiteness`), else inconclusive.
Where: the remaining gap of the adapted model, localised on the one-step rows of every equation
whose target derives from a measured output: the target's derivative estimated from the data,
the unmeasured states taken from the adapted model's free run, and the adapted structure fitted
in two regimes (:func:`.localise.where`, failing side by the global fit). Flagged rows are what
the candidate set did not express.
"""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import torch

from msam_torch.config.to_spec import to_spec
from msam_torch.data.derivatives import METHODS, Auto, DerivativeEstimator
from msam_torch.diagnosis.catalogue import entries as catalogue
from msam_torch.diagnosis.compare import confidence, measures
from msam_torch.diagnosis.compare.verdict import TRY, Verdict, no_gap_verdict, overall
from msam_torch.diagnosis.report.gap_report import EquationGap, GapReport
from msam_torch.diagnosis.stages import localise
from msam_torch.diagnosis.stages.localise import signal_values
from msam_torch.diagnosis.stages.structure import whiteness
from msam_torch.model.notation import format_component, format_equation
from msam_torch.model.spec import Equation, split_derivative
from msam_torch.run.adapt import adapt, nominal_parameters
from msam_torch.run.plan import Plan
from msam_torch.run.progress import LOGGER, step
from msam_torch.run.result import EquationResult, adjusted_columns
from msam_torch.simulation.free_run import FreeRun, free_runs

RECORDS = {"train": "train", "validation": "held_out"}


def diagnose_simulated(plan: Plan, base_dir: Path, options, data=None, validation=None) -> GapReport:
    """:func:`msam_torch.diagnosis.diagnose` for a config evaluated by simulation (``plan``: the
    config's :class:`~msam_torch.run.plan.Plan`). ``data`` and ``validation`` (a path, a DataFrame, a
    mapping of arrays or a :class:`~msam_torch.data.loading.Dataset`) replace the config's training and
    validation records."""
    config = plan.config
    started = time.perf_counter()
    spec = to_spec(config.model)
    parameters = nominal_parameters(config, spec)
    step(LOGGER, "diagnose", "adapting by simulation", 0, 3)
    result = adapt(config, base_dir=base_dir, data=data, validation=validation)
    retuned_theta = {t: th for group in result.data["simulation"] for t, th in group["retuned_theta"].items()}
    unadjusted = lambda eq, theta: EquationResult(eq.target, "", "", [None] * len(eq.components),
                                                  [None] * len(eq.components), theta, {}, {}, [], 0)
    models = {"start": [unadjusted(eq, spec.theta(eq, parameters).tolist()) for eq in spec.equations],
              "retuned": [unadjusted(eq, retuned_theta[eq.target]) for eq in spec.equations],
              "adapted": result.equations}
    step(LOGGER, "diagnose", "free runs of the models", 1, 3)
    runs = free_runs(config, spec, models, base_dir, data=data, validation=validation)
    gap_measures = {"one_step": {}, "free_run": {RECORDS[k]: _free_run_measures(run) for k, run in runs.items()}}
    held_out = runs.get("validation", runs["train"])
    rmse = torch.sqrt(((held_out.simulated - held_out.record.outputs) ** 2).mean((-1, -2)))  # start, retuned, adapted
    target_rms = float(torch.sqrt((held_out.record.outputs**2).mean()))
    significant = bool(confidence.significant(rmse[2], rmse[1], target_rms, options.relative, options.absolute))
    checks = _residual_checks(held_out, spec.inputs, target_rms, options)
    step(LOGGER, "diagnose", "locating the remaining gap", 2, 3)
    series, gaps = {}, []
    for e, (eq, adapted) in enumerate(zip(spec.equations, result.equations)):
        where = _remaining_gap(plan, eq, adapted, runs["train"])
        series[eq.target] = {"where": where["series"]} if where["series"] else {}
        for key, run in runs.items():
            series[eq.target][f"free_run_{RECORDS[key]}"] = _trajectories(run, spec.inputs)
        gaps.append(_equation_gap(eq, adapted, models["start"][e].theta, models["retuned"][e].theta, significant,
                                  rmse, target_rms, where["summary"], checks, options, plan))
    kind, verdict, reasons = overall(gaps, significant, name_targets=True)
    left = [f"{g.target} where {g.where['regions'][0]['rule']}" for g in gaps if g.where["flagged_fraction"] > 0]
    if left:
        verdict += f"; remaining gap not explained by the candidate set ({', '.join(left)})"
    data_info = {"train": result.data["source"], "evaluation": "simulation",
                 "held_out": "validation record" if "validation" in runs else "none (training record)",
                 "nominal_parameters": parameters, "simulation": result.data["simulation"]}
    return GapReport(verdict_kind=kind, verdict=verdict, equations=tuple(gaps), measures=gap_measures, data=data_info,
                     options=asdict(options), config=config.model_dump(mode="json"),
                     seconds=time.perf_counter() - started, reasons=tuple(reasons), series=series)


def _equation_gap(eq: Equation, adapted: EquationResult, start_theta: list, retuned: list, significant: bool,
                  rmse: torch.Tensor, target_rms: float, where: dict, checks: dict, options, plan: Plan) -> EquationGap:
    """One equation's gap: ``rmse`` (3,) is the held-out free-run RMSE of the start, retuned and
    adapted models and ``checks`` the re-fitted start's residual checks (the group's, shared by its
    equations)."""
    index = [i for i, a in enumerate(adapted.adjustments) if a is not None]
    texts = [f.text for f in eq.adjustments]
    spec = to_spec(plan.config.model)
    found = {i: catalogue.effect_entry(eq, i, texts.index(adapted.adjustments[i]), adapted.exponents[i],
                                       adapted.theta[i], start_theta[i], spec)[0] for i in index}
    names = {i: catalogue.NOT_CATALOGUED if e is None else e.name for i, e in found.items()}
    known = [i for i in index if names[i] != catalogue.NOT_CATALOGUED]
    shown = known[0] if known else (index[0] if index else None)
    effect = names[shown] if significant and shown is not None else None
    if adapted.ranking and all(c.get("diverged", False) for c in adapted.ranking):  # nothing was fitted
        significant, effect = False, None
        kind, reasons = Verdict.INCONCLUSIVE, [f"every candidate diverged in the adaptation by simulation: "
                                               f"{eq.target} was not fitted", TRY["adaptation diverged"]]
    elif not significant:
        kind, reasons = no_gap_verdict(checks, TRY["simulated residual"])  # no test functions to widen
    else:
        kind, reasons = (Verdict.EXPLAINED if known else Verdict.NOT_EXPLAINED), []
    label = lambda i: f"{eq.components[i].term.text} -> {eq.components[i].term.text}*{adapted.adjustments[i]}^gamma"
    components = [{"component": eq.components[i].term.text, "best_hypothesis": label(i), "effect": names[i],
                   "exponent": adapted.exponents[i]} for i in index]
    terms = [format_component(eq, i, None, None) for i in range(len(eq.components))]
    return EquationGap(
        target=eq.target, significant=significant, verdict_kind=kind, effect=effect,
        hypothesis=label(shown) if shown is not None else "none", exponent=adapted.exponents[shown] if shown is not None else None,
        catalogue_exponent=catalogue.catalogue_exponent(found[shown]) if effect not in (None, catalogue.NOT_CATALOGUED) else None,
        start_equation=format_equation(eq.target, list(start_theta), terms),
        retuned_equation=format_equation(eq.target, list(retuned), terms), adapted_equation=adapted.equation,
        confidence={"margin": float("nan"), "runner_up": None, "rival": None, "apart_p": 0.0,
                    "win_frequency": float("nan"), "bootstrap_trials": 0, "outcomes": {}},
        improvement={"measure": "held-out free-run RMSE of the outputs", "retuned_rmse": float(rmse[1]),
                     "adapted_rmse": float(rmse[2]), "relative": float(1 - rmse[2] / rmse[1]), "target_rms": target_rms,
                     "rule": {"relative": options.relative, "absolute": options.absolute}},
        structure_left=float((rmse[2] / rmse[1]) ** 2), components=components, ranking=adapted.ranking, where=where,
        checks={**checks, "reasons": reasons},
        estimator={"evaluation": "simulation", "method": plan.config.adaptation.simulation.method,
                   "derivatives": _estimator(plan).name})


def _estimator(plan: Plan) -> DerivativeEstimator:
    """The derivative estimator of the remaining-gap rows (for ``exact``: ``auto``'s)."""
    return plan.derivatives if plan.derivatives.name in METHODS else Auto()


def _remaining_gap(plan: Plan, eq: Equation, adapted: EquationResult, run: FreeRun) -> dict:
    """Where the adapted model still misses, on the one-step rows of ``eq`` (training record);
    nothing is flagged when the target derives from no measured output."""
    base, order = split_derivative(eq.target)
    record = run.record
    if base not in run.outputs:
        return {"summary": {"flagged_fraction": 0.0, "split_explained": 0.0, "time_windows": [], "regions": [],
                            "note": f"{eq.target} derives from no measured output: its rows cannot be formed"},
                "series": None}
    t = record.t
    signals = {"t": t, **dict(zip(run.model.states, run.states[2].unbind(-1))),
               **dict(zip(run.model.external, record.external.unbind(-1)))}
    y = record.outputs[run.outputs.index(base)]
    est = _estimator(plan).estimate(t.cpu().numpy(), y.cpu().numpy(), order, base)
    signals[base] = torch.as_tensor(est.values[0], dtype=t.dtype, device=t.device)
    signals[eq.target] = torch.as_tensor(est.values[order], dtype=t.dtype, device=t.device)
    design = adjusted_columns(eq, adapted, signals)
    where = localise.where(t, design, signals[eq.target], signal_values(eq, signals), orient="global")
    where["summary"]["model"] = where["series"]["model"] = "adapted"
    return where


def _residual_checks(run: FreeRun, inputs, target_rms: float, options) -> dict:
    """The re-fitted start's free-run residual on every output, each sample (independent under
    white measurement noise), checked for whiteness (:func:`.structure.whiteness`, structure relevant
    against the outputs' RMS); a residual within ``options.absolute`` of it passes (``negligible``)."""
    residual = run.record.outputs - run.simulated[1]  # (M, N)
    out = {"ljung_box_p": None, "input_correlation_p": None, "failed": []}
    if not bool(torch.isfinite(residual).all()):
        return {**out, "failed": ["the re-fitted start's free run diverged"]}
    if float(residual.square().mean().sqrt()) <= options.absolute * target_rms:
        return {**out, "negligible": True}
    u = list(_inputs(run, inputs).values())
    found = [whiteness(r, u, options.check_level, target_rms, options.relative, options.absolute) for r in residual]
    p = lambda key: min((f[key] for f in found if f[key] is not None), default=None)
    return {"ljung_box_p": p("ljung_box_p"), "input_correlation_p": p("input_correlation_p"),
            "failed": list(dict.fromkeys(reason for f in found for reason in f["failed"]))}


def _free_run_measures(run: FreeRun) -> dict:
    """NRMSE, sum|eps| and rho per output and model, the mean NRMSE and the gap closed."""
    per_state = {o: measures.by_model(measures.error_measures(run.record.outputs[k], run.simulated[:, k]))
                 for k, o in enumerate(run.outputs)}
    nrmse = torch.tensor([[per_state[o][m]["nrmse"] for m in measures.MODELS] for o in run.outputs]).mean(0)
    closed = measures.closure(nrmse[0:1], nrmse[1:2], nrmse[2:3])
    return {"states": per_state, "measured_states": list(run.outputs), "nrmse": dict(zip(measures.MODELS, nrmse.tolist())),
            "gap_closed": {k: float(v[0]) for k, v in closed.items()}}


def _trajectories(run: FreeRun, inputs) -> dict:
    return {"t": run.record.t, "measured": {o: run.record.outputs[k] for k, o in enumerate(run.outputs)},
            "simulated": {o: run.simulated[:, k] for k, o in enumerate(run.outputs)},
            "inputs": _inputs(run, inputs)}


def _inputs(run: FreeRun, inputs) -> dict:
    """The record's measured inputs by name."""
    return {u: v for u, v in zip(run.model.external, run.record.external.unbind(-1)) if u in inputs}
