"""What a run or a diagnosis that learnt nothing ends with: :class:`~msam_torch.errors.NoInformation`
(exit status 3), its result or report written and saying why, and no equation or verdict printed."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from msam_torch.errors import NoInformation

ZERO = math.sqrt(sys.float_info.epsilon)  # a fitness rho at most this is 0 to the precision it is computed with
UNINFORMED = ("(a model whose outputs stay constant, or move against the measured ones: check the starting "
              "values, model.parameters and adaptation.simulation.initial_guess)")


def require_information(result, path: Path) -> None:
    """A run whose every candidate diverged, whose fitted values are not finite, or whose adapted
    fitness (Eq. 19) is 0 to half the working precision or below, learnt nothing: no equation is printed; ``path`` (written)
    records it."""
    for eq in result.equations:
        if eq.ranking and all(c["diverged"] for c in eq.ranking):
            raise NoInformation(f"{eq.target}: every one of the {len(eq.ranking)} candidates diverged "
                                f"(|gamma| beyond adaptation.gamma_limit or a non-finite fitness); {path} records it")
        values = [*eq.theta, *(g for g in eq.exponents if g is not None), *eq.adapted.values()]
        if not all(math.isfinite(v) for v in values):
            raise NoInformation(f"{eq.target}: the fitted theta, exponents or measures are not finite "
                                f"(check model.parameters and data.parametric_error); {path} records it")
        if eq.adapted["rho"] <= ZERO:
            raise NoInformation(f"{eq.target}: the adapted model's fitness rho (Eq. 19) is {eq.adapted['rho']:.3g}: it "
                                f"predicts nothing of {eq.target} {UNINFORMED}; {path} records it")
    for group in result.data.get("simulation", []):
        for record, rows in group["free_run_rmse"].items():
            if not all(math.isfinite(v) for label, row in rows.items() if label != "start" for v in row):
                raise NoInformation(f"the free run of the adapted {', '.join(group['outputs'])} on the {record} "
                                    f"record is not finite; {path} records it")


def require_diagnosis(report, path: Path) -> None:
    """A diagnosis none of whose hypotheses (candidates, when judged by simulation) converged, whose
    re-fitted and adapted models have no finite held-out measure, or, judged by simulation, whose
    free runs do not correlate with the measured outputs, learnt nothing: no verdict is printed;
    ``path`` (written) records it."""
    from msam_torch.diagnosis.compare.verdict import TRY

    for gap in report.equations:
        if all(c.get("diverged", False) for c in gap.ranking):
            diverged = TRY["adaptation diverged"]
            hint = f" ({diverged})" if diverged in gap.checks.get("reasons", ()) else ""
            raise NoInformation(f"{gap.target}: every hypothesis of the diagnosis diverged or has a non-finite "
                                f"held-out RMSE; {path} records it{hint}")
        if not all(math.isfinite(gap.improvement[k]) for k in ("retuned_rmse", "adapted_rmse")):
            raise NoInformation(f"{gap.target}: the held-out RMSE of the theta re-fitted or adapted model is not "
                                f"finite; {path} records it")
    if report.config.get("adaptation", {}).get("evaluation") == "simulation":  # fitted by their free runs
        for record, runs in report.measures.get("free_run", {}).items():
            rho = {m: max(state[m]["rho"] for state in runs.get("states", {}).values()) for m in ("retuned", "adapted")}
            if rho and max(rho.values()) <= ZERO:
                raise NoInformation(f"the free runs of the theta re-fitted and adapted models do not correlate with "
                                    f"the measured outputs on the {record} record (rho {max(rho.values()):.3g}, Eq. 19) "
                                    f"{UNINFORMED}; {path} records it")
