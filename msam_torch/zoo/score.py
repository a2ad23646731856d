"""Scoring a diagnosis (a :class:`~msam_torch.diagnosis.GapReport`, or its JSON dict) against a
zoo case's truth.

- strict top-1: the withheld effect's equation says "gap explained by" the truth's name, on the
  truth's component and function, exponent within :data:`TOLERANCE` of the truth's (additive or
  multiplicative: both are the power law on that component), and no other equation is flagged;
- null cases: "no significant gap" overall;
- out-of-catalogue cases: a *confident wrong name* is any "gap explained by" verdict but the
  truth's ``expected_name`` (the name a catalogue entry for an input saturation or dead zone would
  carry, :data:`~msam_torch.zoo.effects.EXPECTED_NAMES`) in the truth's equation; the case is
  *answered right* when it reads neither "no significant gap" nor a confident wrong name, and,
  once the catalogue holds an entry of its expected name, when it names that entry;
- every case: a *wrong name* is a "gap explained by" verdict that does not name the truth's
  effect in the truth's equation (any other name on a null or out-of-catalogue case);
- every case: *no gap beside evidence*, an equation reading "no significant gap" while its own
  residual checks failed, or rows of it are flagged by a separate fit that removes a relevant
  share of the squared residual on training and held-out rows (the test of
  :func:`~msam_torch.diagnosis.stages.localise.located`; not where the residual is negligible);
- the theta re-fitted starting model: every theta within 3 % of the truth (null cases);
- held-out free runs: the re-fitted start no worse than the nominal one (1 % slack), and a
  *diverged* run (NRMSE not finite or above :data:`DIVERGED`) beside a verdict that is not
  "inconclusive": of any model, and of the model the verdict rests on
  (:func:`~msam_torch.diagnosis.compare.verdict.rests_on`);
- cases withholding several effects (:mod:`.pairs`): how many of them the effects added in turn
  (the report's ``in_turn``) found, in any order; every case: the *spurious* effects added in turn
  (matching no withheld effect).
"""
from __future__ import annotations

import math
import re

from msam_torch.diagnosis.catalogue.entries import TOLERANCE, entries  # TOLERANCE: of a right functional form
from msam_torch.diagnosis.compare.comparison import (
    DIVERGED,  # the held-out free-run NRMSE beyond which a run has diverged
)
from msam_torch.diagnosis.compare.verdict import Verdict, rests_on
from msam_torch.diagnosis.stages.localise import MIN_EXPLAINED
from msam_torch.diagnosis.stages.structure import relevant

THETA_TOLERANCE = 0.03
NO_WORSE_SLACK = 0.01
_TERM = re.compile(r"([+-])?\s*(\d[\d.]*(?:e[+-]?\d+)?)\s+(\([^()]*\)|[^\s+-]\S*)")  # a constant (no term) is skipped


def _as_dict(report) -> dict:
    return report if isinstance(report, dict) else report.to_dict()


def explained(verdict: str) -> bool:
    return verdict.startswith("gap explained")


def parse_equation(text: str) -> dict:
    """``'x_ddot = -0.5 x_dot - 6 x + 1 u'`` -> ``{'x_dot': -0.5, 'x': -6.0, 'u': 1.0}``."""
    rhs = text.split("=", 1)[1]
    out = {}
    for sign, number, term in _TERM.findall(rhs):
        out[_plain(term)] = -float(number) if sign == "-" else float(number)
    return out


def _plain(term: str) -> str:
    """A term as the zoo writes it: ``'(x1 - x2)'`` -> ``'x1 - x2'`` (a difference is printed in parentheses)."""
    return term[1:-1] if term.startswith("(") and term.endswith(")") else term


def _component(hypothesis: str) -> str:
    """The component of a hypothesis label (``'(x1 - x2) + (x1 - x2)*abs(x1 - x2)^gamma'`` -> ``'x1 - x2'``)."""
    return _plain(re.split(r" \+ | -> ", hypothesis, maxsplit=1)[0])


def effect_matches(gap: dict, truth: dict) -> bool:
    """``gap`` (one equation of a report) names the truth's effect in its form (see module doc)."""
    return explained(gap["verdict"]) and step_matches(gap, truth)


def step_matches(step: dict, truth: dict) -> bool:
    """An effect (an equation's, or a step of the report's ``in_turn``: ``effect``, ``hypothesis``,
    ``exponent``) is the truth's: its name, component, function and exponent."""
    if not step.get("effect") or truth["name"].lower() not in step["effect"].lower():
        return False
    hypothesis = step["hypothesis"]
    return (_component(hypothesis) == truth["component"] and f"abs({truth['function']})" in hypothesis
            and step["exponent"] is not None and abs(step["exponent"] - truth["exponent"]) <= TOLERANCE)


def score(report, truth: dict) -> dict:
    """The figures of one case (None where a figure does not apply)."""
    r = _as_dict(report)
    gaps = {g["target"]: g for g in r["equations"]}
    kind = truth["kind"]
    out = {"verdict": r["verdict"], "top1": None, "no_gap": None, "confident_wrong": None, "theta_ok": None}
    if kind == "catalogued":
        others_quiet = all(not g["significant"] for t, g in gaps.items() if t not in truth["targets"])
        out["top1"] = others_quiet and all(effect_matches(gaps[t], truth) for t in truth["targets"])
    elif kind == "null":
        out["no_gap"] = r["verdict"] == Verdict.NO_GAP.text()  # the verdict, not only no significant effect
        out["theta_ok"] = theta_within(gaps, truth["theta"], THETA_TOLERANCE)
    elif kind == "several":  # both found among the effects added in turn, in either order
        steps = r.get("in_turn", {}).get("effects", [])
        out["found"] = sum(any(step_matches(s, t) and s["target"] == t["target"] for s in steps)
                           for t in truth["effects"])
        out["all_found"] = out["found"] == len(truth["effects"])
    else:
        expected = truth.get("expected_name")
        named = [t for t, g in gaps.items() if explained(g["verdict"])]
        out["confident_wrong"] = any(not _names(gaps[t], t, truth, expected) for t in named)
        out["answered_right"] = (any(_names(gaps[t], t, truth, expected) for t in named) if catalogued(expected)
                                 else not out["confident_wrong"] and r["verdict"] != Verdict.NO_GAP.text())
    if kind != "several":
        name = truth["name"] if kind == "catalogued" else truth.get("expected_name")
        out["wrong_name"] = any(explained(g["verdict"]) and not _names(g, t, truth, name) for t, g in gaps.items())
    out["no_gap_beside_evidence"] = sum(no_gap_beside_evidence(g, r.get("options") or {}) for g in gaps.values())
    steps = r.get("in_turn", {}).get("effects", [])
    real = truth.get("effects", [truth] if kind == "catalogued" else [])
    out["spurious"] = sum(not any(step_matches(s, t) and s["target"] == t["target"] for t in real) for s in steps)
    free = r.get("measures", {}).get("free_run", {}).get("held_out", {}).get("nrmse")
    if free:
        nrmse = {k: float(v) if v is not None else math.inf for k, v in free.items()}
        diverged = any(not math.isfinite(v) or v > DIVERGED for v in nrmse.values())
        out["diverged_beside_verdict"] = diverged and r["verdict_kind"] != Verdict.INCONCLUSIVE
        own = rests_on(Verdict(r["verdict_kind"]))
        out["own_run_diverged"] = (r["verdict_kind"] != Verdict.INCONCLUSIVE
                                   and not (math.isfinite(nrmse[own]) and nrmse[own] <= DIVERGED))
        out["retuned_no_worse"] = (math.isfinite(nrmse["retuned"])
                                   and nrmse["retuned"] <= (1 + NO_WORSE_SLACK) * nrmse["start"])
        out["free_run_nrmse"] = nrmse
    return out


def _names(gap: dict, target: str, truth: dict, name: str | None) -> bool:
    """``gap``'s verdict names ``name`` in one of the truth's equations."""
    return name is not None and target in truth["targets"] and name.lower() in gap["verdict"].lower()


def catalogued(name: str | None) -> bool:
    """Whether the bundled catalogue holds an entry of this name (a part of an entry's name)."""
    return name is not None and any(name in e.name.lower() for e in entries())


def no_gap_beside_evidence(gap: dict, options: dict) -> bool:
    """``gap`` reads "no significant gap" while its own evidence shows one (see module doc)."""
    if gap["verdict"] != Verdict.NO_GAP.text():
        return False
    checks, where = gap.get("checks") or {}, gap.get("where") or {}
    shares = [where.get("split_explained"), where.get("held_out_explained")]
    flagged = bool(where.get("flagged_fraction")) and shares[0] is not None and all(
        share is None or (share >= MIN_EXPLAINED and relevant(share, where["residual_rms"], where["target_rms"],
                                                             options["relative"], options["absolute"]))
        for share in shares)
    return bool(checks.get("failed")) or (flagged and not checks.get("negligible"))


def theta_within(gaps: dict, theta: dict, tolerance: float) -> bool:
    """Every re-fitted theta of every equation within ``tolerance`` (relative) of the truth."""
    for target, true in theta.items():
        fitted = parse_equation(gaps[target]["retuned_equation"])
        for term, value in true.items():
            if term not in fitted or abs(fitted[term] - value) > tolerance * abs(value):
                return False
    return True


def outcome(row: dict) -> str:
    """The class of our answer on one case (the failure classes of the report)."""
    ours, truth = row["ours"], row["truth"]
    if "error" in ours:
        return "error"
    verdicts = {t: e["verdict"] for t, e in ours["equations"].items()}
    flagged = [t for t, v in verdicts.items() if v != Verdict.NO_GAP.text()]
    named = [t for t, v in verdicts.items() if explained(v)]
    undecided = all(verdicts[t] == Verdict.INCONCLUSIVE.text() for t in flagged)
    no_gap = ours["verdict"] == Verdict.NO_GAP.text()  # where no equation is flagged, the verdict tells
    if truth["kind"] != "catalogued":
        return (("no gap" if no_gap else "inconclusive") if not flagged else "named an effect" if named
                else "inconclusive" if undecided else "gap, not explained")
    if ours["top1"]:
        return "top-1"
    targets = truth["targets"]
    if not any(t in flagged for t in targets):
        return ("another equation flagged, not the truth's" if flagged else "no significant gap" if no_gap
                else "inconclusive")
    target = targets[0]
    if target not in named:
        return ("inconclusive" if verdicts[target] == Verdict.INCONCLUSIVE.text()
                else "gap, not explained (no catalogued name)")
    if truth["name"].lower() not in verdicts[target].lower():
        return "wrong name (confident)"
    if any(t not in targets for t in flagged):
        return "right name, another equation also flagged"
    return "right name, exponent or component outside the tolerance"


def outcome_table(rows: list[dict]) -> str:
    """Counts of :func:`outcome` per kind of case, with example seeds."""
    lines = ["| case kind | outcome | cases | example seeds |", "|---|---|---|---|"]
    for kind in ("catalogued", "null", "out_of_catalogue"):
        part = [r for r in rows if r["truth"]["kind"] == kind]
        classes = sorted({outcome(r) for r in part})
        for c in sorted(classes, key=lambda c: -sum(outcome(r) == c for r in part)):
            seeds = [r["seed"] for r in part if outcome(r) == c]
            lines.append(f"| {kind} | {c} | {len(seeds)} | {', '.join(map(str, seeds[:8]))} |")
    return "\n".join(lines)
