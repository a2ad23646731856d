"""One state equation's diagnosis, stage by stage: weak-form rows (:mod:`msam_torch.diagnosis.stages.rows`) -> every
hypothesis fitted at once (:mod:`msam_torch.diagnosis.effects.hypotheses`) -> held-out RMSE -> bootstrap trials
(:mod:`msam_torch.diagnosis.effects.bootstrap`) -> catalogue names (:mod:`msam_torch.diagnosis.catalogue.naming`) -> null rule and confidence
(:mod:`msam_torch.diagnosis.compare.confidence`) -> residual structure left (:mod:`.structure`) -> verdict (:mod:`msam_torch.diagnosis.compare.verdict`)
-> where the starting model fails (:mod:`.localise`)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from msam_torch.data.loading import Dataset
from msam_torch.diagnosis.catalogue import entries as catalogue
from msam_torch.diagnosis.catalogue.naming import Naming, name_hypotheses, pinned, pinned_signs, repeated
from msam_torch.diagnosis.compare import confidence
from msam_torch.diagnosis.compare.comparison import models
from msam_torch.diagnosis.compare.intervals import term_intervals
from msam_torch.diagnosis.compare.verdict import Verdict, equation_verdict
from msam_torch.diagnosis.effects.bootstrap import bootstrap
from msam_torch.diagnosis.effects.hypotheses import (
    COPIES,
    Fitted,
    Hypothesis,
    crossed_errors,
    encode,
    enumerate_hypotheses,
    exponent,
    extended_equation,
    fit,
    fitted_text,
    heldout_errors,
    heldout_rmse,
    offset_testable,
    references,
    slot,
)
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.report.gap_report import EquationGap
from msam_torch.diagnosis.stages.localise import implicated, located, starting_where
from msam_torch.diagnosis.stages.rows import WeakForm
from msam_torch.diagnosis.stages.structure import residual_checks, structure_left
from msam_torch.engine.values import StepOptions
from msam_torch.engine.weak_form import target_source
from msam_torch.model.expressions import parse
from msam_torch.model.notation import format_component, format_equation
from msam_torch.model.spec import Equation, ModelSpec
from msam_torch.run.estimation import Estimation
from msam_torch.simulation.equations import EquationModel


@dataclass(frozen=True)
class EquationDiagnosis:
    """The gap of one equation, its models for the comparison (:func:`~msam_torch.diagnosis.compare.comparison.compare`) and the
    arrays its plots draw."""

    gap: EquationGap
    model: EquationModel
    series: dict


def diagnose_equation(spec: ModelSpec, equation: Equation, train: Dataset, estimation: Estimation,
                      parameters: dict, options: DiagnoseOptions, generator: torch.Generator) -> EquationDiagnosis:
    """The stages of the diagnosis of ``equation`` (module docstring) on the signals and
    half-width of ``estimation``; ``generator`` draws the bootstrap trials."""
    # every hypothesis (exchange laws where a signal exchanges with one of its own quantity)
    nominal = spec.theta(equation, parameters)
    exchanging = catalogue.Roles.of_equation(spec, equation).exchanging(equation, nominal)
    hypotheses = enumerate_hypotheses(equation, exchanging, offset=offset_testable(equation, estimation.train))
    # weak-form rows of the equation extended by a copy of every adjustable component
    extended = extended_equation(equation, references(hypotheses))
    weak = WeakForm.build(extended, estimation.train, estimation.held_out, estimation.half_width, options.blocks)
    t = weak.signals["t"]
    nominal = nominal.to(t)
    # every hypothesis fitted at once, scored on the held-out rows
    choices, starts = encode(equation, hypotheses, t.device)
    q = len(equation.adjustable)
    step_options = StepOptions(scaling="gauss_newton", step_size="one", theta="varpro", damping=options.damping)
    original = fit(weak.data, choices, starts, step_options, options.steps, q)
    errors = heldout_errors(weak.val_data, weak.val_rows, choices, original)  # (1, C, M')
    rmse, errors = heldout_rmse(errors, original)[0], errors[0]  # (C,), (C, M')

    # bootstrap trials: time blocks and measurement noise; copies with the measured states' noise doubled
    source, order = target_source(extended, weak.signals)
    # white noise keeps about 1 / decimation of its power through the anti-alias filter; interpolated
    # between samples it is integrated as on the samples (a test function's norm there is sqrt(k) larger)
    levels = {k: float(v) for k, v in train.info.get("noise_level", {}).items() if v and k in weak.signals}
    noise = levels.get(source, 0.0) * (estimation.refinement / estimation.decimation)**0.5
    states = {k: v for k, v in levels.items() if k not in spec.inputs}
    again = lambda copies: estimation.noise(states, copies, generator)
    boot = bootstrap(weak, choices, q, original, rmse, noise, order, again, options, step_options, generator)

    # catalogue names within each hypothesis's bootstrap interval of its total exponent
    named = name_hypotheses(spec, equation, hypotheses, original, boot, nominal)
    names = named.names

    # null rule on the best effect; how often it wins the bootstrap trials
    # (a start of a form that ended within the interval of its best start is that estimate again)
    is_effect = torch.tensor([h.kind != "retuned" for h in hypotheses], device=t.device) & named.admissible \
        & ~repeated(hypotheses, named, rmse)
    best = int(confidence.best_effect(rmse, is_effect))
    target_rms = weak.target_rms
    is_significant = bool(confidence.significant(rmse[best], rmse[0], target_rms, options.relative, options.absolute))
    outcome = names[best] if is_significant else Verdict.NO_GAP.text()
    trial_outcomes = []
    if boot is not None:
        trial_outcomes = confidence.outcomes([names] * boot.rmse.shape[0], boot.rmse, is_effect, target_rms, options)
    # the evidence a name is told apart on: held-out rows, and training rows each predicted by a fit of the others
    reach = estimation.reach
    crossed = torch.full((len(hypotheses), int(weak.fit_rows.sum())), torch.nan, dtype=t.dtype, device=t.device)
    rivals = None
    if is_significant:
        effects = is_effect.nonzero().squeeze(-1)
        crossed[effects] = crossed_errors(weak, choices[effects], original.gamma[0, effects], step_options,
                                          options.bootstrap_steps, q, options.blocks, reach)
        rivals = _pinned_rivals(spec, extended, equation, hypotheses, weak, choices, starts, step_options, nominal,
                                options.blocks, reach)
    evidence = confidence.Evidence(errors, crossed, weak.independence(reach))
    sure = confidence.summary(rmse, names, best, is_significant, outcome, trial_outcomes, is_effect, evidence,
                              options.relative, generator, rivals)

    # verdict (with the residual structure the effect leaves), and where the starting model fails
    structure = structure_left(equation, weak, choices, original, best)
    checks = residual_checks(equation, weak, choices, original, [u for u in spec.inputs if u in weak.val_signals],
                             options.check_level, options.max_residual_structure, options.absolute,
                             options.relative, estimation.reach,
                             noise * float(torch.linalg.vector_norm(weak.val_tests.kernels[order])))
    where = starting_where(equation, weak.signals, None if weak.val_signals is weak.signals else weak.val_signals)
    kind, reasons = equation_verdict(is_significant, outcome, sure, structure, checks, options,
                                     _loose(equation, hypotheses, named, rmse, best if is_significant else 0, target_rms,
                                            options),
                                     located(equation, where["summary"], options.relative, options.absolute))
    winner = best if is_significant else 0
    fixed = implicated(equation, where["summary"]) if kind is Verdict.NOT_EXPLAINED and not is_significant else []
    if fixed:
        signal = where["summary"]["regions"][0]["signal"]
        reasons = [*reasons, _freed_finding(spec, equation, fixed, signal, train, estimation, parameters, options,
                                            generator)]

    text = lambda c: fitted_text(extended, equation, choices, original, c, weak.scale)
    gap = EquationGap(
        target=equation.target, significant=is_significant, verdict_kind=kind,
        effect=outcome if is_significant else None,
        hypothesis=hypotheses[winner].label(equation),
        exponent=exponent(hypotheses[winner], equation, original.gamma[0, winner]),
        catalogue_exponent=named.catalogue_exponent(winner),
        naming=None if not is_significant else
        {**named.details[winner], "at_catalogue_exponent": confidence.at_catalogue_exponent(rivals, _form(hypotheses, winner),
                                                                                             outcome)},
        start_equation=format_equation(equation.target, nominal.tolist(),
                                       [format_component(equation, i, None, None) for i in range(len(equation.components))]),
        retuned_equation=text(0), adapted_equation=text(winner), confidence=sure,
        improvement={"retuned_rmse": float(rmse[0]), "adapted_rmse": float(rmse[winner]),
                     "relative": float(1 - rmse[winner] / rmse[0]), "target_rms": target_rms,
                     "rule": {"relative": options.relative, "absolute": options.absolute}},
        structure_left=structure, components=_components(equation, hypotheses, rmse),
        ranking=_ranking(equation, hypotheses, rmse, names, named, original, text), where=where["summary"],
        estimator={"test_function": "bump (1-s^2)^4", "half_width": weak.tests.half_width * weak.tests.dt,
                   "half_width_samples": weak.tests.half_width / estimation.refinement,  # of the (decimated) record
                   "rows": weak.rows, **estimation.info},
        checks={**checks, "reasons": reasons},
        intervals=term_intervals(extended, equation, choices, original, boot, winner, weak.scale),
    )
    model = models(extended, equation, nominal, choices, original, boot, winner, is_effect, weak.scale)
    return EquationDiagnosis(gap, model, {"where": where["series"]})


def freed(equation: Equation, fixed: list[int], signal: str) -> Equation:
    """``equation`` with its ``fixed`` components adjustable by ``abs(signal)`` (added to the
    adjustment set where missing; the other components keep the functions they had)."""
    texts = [f.text for f in equation.adjustments]
    function = f"abs({signal})"
    adjustments = equation.adjustments if function in texts else (
        *equation.adjustments, parse(function, f"{equation.target}: {function}", {signal}))
    index = [f.text for f in adjustments].index(function)
    components = tuple(
        replace(c, adjustable=True, allowed=(index,)) if i in fixed else
        replace(c, allowed=equation.allowed(i)) if c.adjustable else c
        for i, c in enumerate(equation.components))
    return replace(equation, components=components, adjustments=adjustments)


def _freed_finding(spec: ModelSpec, equation: Equation, fixed: list[int], signal: str, train: Dataset,
                   estimation: Estimation, parameters: dict, options: DiagnoseOptions, generator: torch.Generator) -> str:
    """What the same diagnosis finds with the ``fixed`` components that read the located region's
    ``signal`` made adjustable (:func:`freed`): its verdict, best hypothesis and held-out gain."""
    gap = diagnose_equation(spec, freed(equation, fixed, signal), train, estimation, parameters, options, generator).gap
    names = ", ".join(equation.components[i].term.text for i in fixed)
    if not gap.significant:
        return f"tested with {names} adjustable by abs({signal}): still {gap.verdict}"
    return (f"tested with {names} adjustable by abs({signal}): {gap.verdict}, best {gap.hypothesis} (exponent "
            f"{gap.exponent:.3g}, {gap.effect}), held-out RMSE {100 * gap.improvement['relative']:.1f} % below the "
            f"re-fitted start's: {gap.adapted_equation}")


def _pinned_rivals(spec: ModelSpec, extended: Equation, equation: Equation, hypotheses: list[Hypothesis],
                   weak: WeakForm, choices: torch.Tensor, starts: torch.Tensor, step_options: StepOptions,
                   nominal: torch.Tensor, folds: int, reach: int) -> confidence.Pinned | None:
    """Out-of-sample evidence (:class:`~msam_torch.diagnosis.compare.confidence.Evidence`), entry names and fitted equations of
    the effect hypotheses pinned at catalogue exponents (:func:`~msam_torch.diagnosis.catalogue.naming.pinned`) whose fitted theta
    has the sign their entry asks and whose held-out errors are finite; None without any."""
    pins = pinned(spec, equation, hypotheses)
    if not pins:
        return None
    rows = torch.tensor([p.hypothesis for p in pins], device=choices.device)
    start = starts[rows].clone()
    for k, p in enumerate(pins):
        start[k, slot(equation, hypotheses[p.hypothesis])] = p.gamma
    q = len(equation.adjustable)
    fitted = fit(weak.data, choices[rows], start, step_options, 0, q)  # theta at the pins
    held_out = heldout_errors(weak.val_data, weak.val_rows, choices[rows], fitted)[0]
    keep = [k for k, ok in enumerate(pinned_signs(pins, hypotheses, equation, fitted.theta[0], nominal))
            if ok and bool(torch.isfinite(held_out[k]).all())]
    if not keep:
        return None
    crossed = crossed_errors(weak, choices[rows[keep]], fitted.gamma[0, keep], step_options, 0, q, folds, reach)
    evidence = confidence.Evidence(held_out[keep], crossed, weak.independence(reach))
    return confidence.Pinned(evidence, [pins[k].entry.name for k in keep],
                             [fitted_text(extended, equation, choices[rows], fitted, k, weak.scale) for k in keep],
                             [pins[k].hypothesis for k in keep])


def _loose(equation: Equation, hypotheses: list[Hypothesis], named: Naming, rmse: torch.Tensor, reference: int,
           target_rms: float, options: DiagnoseOptions) -> str | None:
    """The law held too loosely to be an effect (:attr:`~msam_torch.diagnosis.catalogue.naming.Naming.loose`) with the least
    held-out RMSE, where it beats the ``reference`` hypothesis (the best effect, else the re-fitted
    start) by the null rule's margin: what it is and what it beats; else None."""
    candidates = named.loose & torch.isfinite(rmse)
    if not bool(candidates.any()):
        return None
    c = int(torch.where(candidates, rmse, torch.full_like(rmse, torch.inf)).argmin())
    if not bool(confidence.significant(rmse[c], rmse[reference], target_rms, options.relative, options.absolute)):
        return None
    beaten = "the re-fitted start" if reference == 0 else f"the best effect whose exponent is held ({named.names[reference]})"
    d = named.details[c]
    within = f" ({' and '.join(d['consistent'])} within)" if d["consistent"] else ""
    return (f"the law {hypotheses[c].label(equation)} predicts the held-out rows better than {beaten}, RMSE "
            f"{float(rmse[c]):.4g} vs {float(rmse[reference]):.4g}, but holds its exponent only to "
            f"{d['total_exponent']:.2f} ± {d['half_width']:.2f} on {d['on']}{within}")


def _form(hypotheses: list[Hypothesis], c: int) -> set[int]:
    """The hypotheses of ``c``'s form (:attr:`~msam_torch.diagnosis.effects.hypotheses.Hypothesis.form`): its starts."""
    return {k for k, h in enumerate(hypotheses) if h.form == hypotheses[c].form}


def _components(equation: Equation, hypotheses: list[Hypothesis], rmse: torch.Tensor) -> list[dict]:
    """Adjustable components ranked by how much their best hypothesis improves the held-out RMSE."""
    components = []
    for i in equation.adjustable:
        touching = [c for c, h in enumerate(hypotheses) if h.component == i]
        c = min(touching, key=lambda c: float(rmse[c]))
        components.append({"component": equation.components[i].term.text, "best_hypothesis": hypotheses[c].label(equation),
                           "heldout_rmse": float(rmse[c]), "improvement": float(1 - rmse[c] / rmse[0])})
    return sorted(components, key=lambda d: -d["improvement"])


def _ranking(equation: Equation, hypotheses: list[Hypothesis], rmse: torch.Tensor, names: list[str],
             named: Naming, original: Fitted, text) -> list[dict]:
    """Every valid hypothesis, best held-out RMSE first; ``start``: the exponent a fit of several starts
    (an additive or exchange copy) started from, which tells its rows apart."""
    ranked = [int(c) for c in torch.argsort(rmse) if torch.isfinite(rmse[c])]
    return [{"hypothesis": hypotheses[c].label(equation), "kind": hypotheses[c].kind, "effect": names[c],
             "start": hypotheses[c].start if hypotheses[c].kind in COPIES else None,
             "exponent": exponent(hypotheses[c], equation, original.gamma[0, c]),
             "catalogue_exponent": named.catalogue_exponent(c),
             "equation": text(c), "heldout_rmse": float(rmse[c]), "improvement": float(1 - rmse[c] / rmse[0])}
            for c in ranked]
