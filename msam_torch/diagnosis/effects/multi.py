"""Several effects in turn (docs/design.md section 3): after a diagnosis accepts an effect, the
adapted structure becomes the starting model (:mod:`.adapted`) and the diagnosis runs again on
what remains: where the remaining gap lies (the localised windows of the new start), which
effect explains it, and whether adding it shrinks the held-out gap by the same null rule and
verdict checks the first effect passed (:func:`~msam_torch.diagnosis.compare.verdict.equation_verdict`; no threshold of its own).
The loop stops when no significant gap remains, when the next effect is not accepted, or after
``max_effects`` steps.

Two effects missing at once bias the fit of either alone (a cubic stiffness fitted while quadratic
drag is missing reads exponent 3.3, outside the catalogue's interval), so a significant effect
that is not explained, or not told apart from a rival, is added *provisionally*: when the
diagnosis beside it accepts an effect, that effect is added to the model without the provisional
one, and the loop goes on from there (the provisional effect, now unbiased, may be accepted in the
next step). Nothing provisional is ever kept or reported as accepted.

The report returned is the first diagnosis (of the user's starting model) with ``in_turn``: every
accepted effect in order with the held-out gap before and after it (weak-form RMSE and free-run
NRMSE; for an effect found beside a provisional one, of the models holding it), why the loop
stopped, the model with every accepted effect in, theta re-fitted (``accepted_model``; ``GapReport.accepted``: its
fitted models, for ``GapReport.model("accepted")``) and the number of diagnoses run; its verdict names the accepted effects
in order, its ``seconds`` are those of all the diagnoses.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, Optional

from msam_torch.config.schema import Config
from msam_torch.diagnosis.compare.verdict import Verdict, free_run_reasons
from msam_torch.diagnosis.effects.adapted import without
from msam_torch.diagnosis.report.gap_report import GapReport

Adapt = Callable[[list], Config]  # the config with the effects of these equations added
Round = Callable[[Config], "tuple[GapReport, Optional[Adapt]]"]  # one diagnosis, and how to adapt its model
STOPPED = {Verdict.NO_GAP: "no significant gap remains",
           Verdict.NOT_EXPLAINED: "no effect accepted: the remaining gap is not explained by a catalogued effect",
           Verdict.INCONCLUSIVE: "no effect accepted: the diagnosis of the remaining gap is inconclusive"}


def in_turn(config: Config, diagnose_round: Round, max_effects: int) -> GapReport:
    """Diagnose ``config``, then the adapted structure, and so on (module docstring);
    ``diagnose_round(config)`` returns a report and a function adding the effects of the given
    equations to ``config`` (None when the structure cannot be diagnosed further)."""
    seconds = []

    def timed(config: Config):
        result = diagnose_round(config)
        seconds.append(result[0].seconds)
        return result

    first, adapt = timed(config)
    report, model, steps, step = first, config, [], 1
    while True:
        found, beside = report, None
        if adapt is not None and _unexplained(report):
            provisional = adapt([g.target for g in report.equations if g.significant])
            found, adapt_beside = timed(provisional)
            beside = [g.adapted_equation for g in report.equations if g.significant]
        if found.verdict_kind is not Verdict.EXPLAINED:
            stopped = STOPPED[report.verdict_kind] + "".join(f"; {r}" for r in report.reasons)
            if beside is not None:
                stopped += "; nor beside the best power law added provisionally"
            last, adapted = report, ()  # the model diagnosed last, theta re-fitted
            break
        accepted = [g.target for g in found.equations if g.verdict_kind is Verdict.EXPLAINED]
        steps += [_step(found, g, step, beside) for g in found.equations if g.target in accepted]
        limit = None if step < max_effects else f"the most effects in turn ({max_effects}, --max-effects) were added"
        if adapt is None:
            limit = "the adapted structure is not diagnosed further (evaluated by simulation)"
        if limit and beside is None:
            stopped, last, adapted = limit, found, accepted
            break
        model = adapt(accepted) if beside is None else without(adapt_beside(accepted), model, provisional)
        report, adapt = timed(model)
        if limit:  # the model without the provisional effect, diagnosed for its equations
            stopped, last, adapted = limit, report, ()
            break
        step += 1
    several = len(first.equations) > 1
    named = [s["effect"] + (f" in {s['target']}" if several else "") for s in steps]
    kept = not steps or (first.verdict_kind is Verdict.EXPLAINED and all(s["step"] == 1 for s in steps))
    verdict = first.verdict if kept else Verdict.EXPLAINED.text(", then ".join(named))
    kind = Verdict.EXPLAINED if steps else first.verdict_kind
    stages = tuple("adapted" if g.target in adapted else "retuned" for g in last.equations)
    return replace(first, verdict_kind=kind, verdict=verdict, seconds=sum(seconds),
                   in_turn={"effects": steps, "stopped": stopped, "accepted_model": _equations(last, adapted),
                            "diagnoses": len(seconds)},
                   accepted={"config": last.config, "models": last.models, "stages": stages})


def _unexplained(report: GapReport) -> bool:
    """Whether a significant gap is left that no effect explains, "not explained" or inconclusive
    only because its best fit is not told apart from a rival, every other equation without a gap,
    and the free runs raise no doubt: a gap to add the best power law to provisionally."""
    gaps, unsettled = report.equations, (Verdict.NOT_EXPLAINED, Verdict.INCONCLUSIVE)
    return (any(g.significant for g in gaps)
            and all(g.verdict_kind in unsettled if g.significant else g.verdict_kind is Verdict.NO_GAP for g in gaps)
            and not free_run_reasons(report.measures.get("free_run", {}), Verdict.NOT_EXPLAINED))


def _equations(report: GapReport, adapted) -> dict:
    """Per equation: its adapted equation (targets in ``adapted``) or its theta re-fitted one."""
    return {g.target: g.adapted_equation if g.target in adapted else g.retuned_equation for g in report.equations}


def _step(report: GapReport, gap, step: int, beside: list | None) -> dict:
    """One accepted effect: what it is and the held-out gap before and after adding it (``beside``:
    the equations the provisional effect it was found beside)."""
    free = report.measures.get("free_run", {})
    label = "held_out" if "held_out" in free else "train"
    nrmse = free.get(label, {}).get("nrmse", {})
    return {"step": step, "target": gap.target, "effect": gap.effect, "hypothesis": gap.hypothesis,
            "exponent": gap.exponent, "naming": gap.naming["text"] if gap.naming else None,
            "win_frequency": gap.confidence["win_frequency"], "starting_equation": gap.start_equation,
            "adapted_equation": gap.adapted_equation, "beside_provisional": beside,
            "heldout_rmse": {"before": gap.improvement["retuned_rmse"], "after": gap.improvement["adapted_rmse"],
                             "relative": gap.improvement["relative"]},
            "free_run_nrmse": {"data": label, "before": nrmse.get("retuned"), "after": nrmse.get("adapted")}}
