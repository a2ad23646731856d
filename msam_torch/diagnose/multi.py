"""Several effects in turn (docs/design.md section 3): after a diagnosis accepts an effect, the
adapted structure becomes the starting model (:mod:`.adapted`) and the diagnosis runs again on
what remains: where the remaining gap lies (the localised windows of the new start), which
effect explains it, and whether adding it shrinks the held-out gap by the same null rule and
verdict checks the first effect passed (:func:`.verdict.equation_verdict`; no threshold of its own).
The loop stops when no significant gap remains, when the next effect is not accepted (not
explained, or inconclusive), or after ``max_effects`` steps.

The report returned is the first diagnosis (of the user's starting model) with ``in_turn``: every
accepted effect in order with the held-out gap before and after it (weak-form RMSE and free-run
NRMSE), why the loop stopped, and the final model.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, Optional

from ..config import Config
from .report import GapReport
from .verdict import Verdict

Round = Callable[[Config], "tuple[GapReport, Optional[Config]]"]  # one diagnosis and its adapted config
STOPPED = {Verdict.NO_GAP: "no significant gap remains",
           Verdict.NOT_EXPLAINED: "no effect accepted: the remaining gap is not explained by the candidate set",
           Verdict.INCONCLUSIVE: "no effect accepted: the diagnosis of the remaining gap is inconclusive"}


def in_turn(config: Config, diagnose_round: Round, max_effects: int) -> GapReport:
    """Diagnose ``config``, then the adapted structure, and so on (module docstring);
    ``diagnose_round(config)`` returns a report and the config with its accepted effects added
    (None when the structure cannot be diagnosed further)."""
    first, adapted = diagnose_round(config)
    report, steps, final, step = first, [], {}, 1
    while True:
        if report.verdict_kind is not Verdict.EXPLAINED:
            stopped = STOPPED[report.verdict_kind] + "".join(f"; {r}" for r in report.reasons)
            break
        accepted = [g for g in report.equations if g.verdict_kind is Verdict.EXPLAINED]
        steps += [_step(report, g, step) for g in accepted]
        final = {g.target: g.adapted_equation if g.verdict_kind is Verdict.EXPLAINED else g.retuned_equation
                 for g in report.equations}
        if step >= max_effects:
            stopped = f"the most effects in turn ({max_effects}, --max-effects) were added"
            break
        if adapted is None:
            stopped = "the adapted structure is not diagnosed further (evaluated by simulation)"
            break
        report, adapted = diagnose_round(adapted)
        step += 1
    summary = {"effects": steps, "stopped": stopped, "final_model": final}
    several = len(first.equations) > 1
    verdict = first.verdict + "".join(f", then {s['effect']}" + (f" in {s['target']}" if several else "")
                                      for s in steps if s["step"] > 1)
    return replace(first, verdict=verdict, in_turn=summary)


def _step(report: GapReport, gap, step: int) -> dict:
    """One accepted effect: what it is and the held-out gap before and after adding it."""
    free = report.measures.get("free_run", {})
    label = "held_out" if "held_out" in free else "train"
    nrmse = free.get(label, {}).get("nrmse", {})
    return {"step": step, "target": gap.target, "effect": gap.effect, "hypothesis": gap.hypothesis,
            "exponent": gap.exponent, "naming": gap.naming["text"] if gap.naming else None,
            "win_frequency": gap.confidence["win_frequency"], "starting_equation": gap.start_equation,
            "adapted_equation": gap.adapted_equation,
            "heldout_rmse": {"before": gap.improvement["retuned_rmse"], "after": gap.improvement["adapted_rmse"],
                             "relative": gap.improvement["relative"]},
            "free_run_nrmse": {"data": label, "before": nrmse.get("retuned"), "after": nrmse.get("adapted")}}
