"""``msam run`` beside ``msam diagnose`` on a zoo case (issue 54: one answer for one record).

On a case whose diagnosis names an effect, ``msam run`` with the config's defaults
(:func:`msam_torch.run.adapt.adapt`) must either adapt the same law or state the diagnosis's
reading and why its own differs: the lines it prints at its end
(:func:`msam_torch.diagnosis.agreement.agreement`, given the same diagnosis) are read back per
named equation as *same law*, *states the difference*, or neither.
"""
from __future__ import annotations

from pathlib import Path

from msam_torch.config.schema import load_config
from msam_torch.diagnosis.agreement import agreement
from msam_torch.diagnosis.compare.verdict import Verdict

SAME, DIFFERS = "run's adapted structure reads the same law", "run's adapted structure differs"


def read_back(lines: list[str], target: str) -> str:
    """'same', 'stated' or 'neither': what run's closing ``lines`` say of a named equation."""
    for k, line in enumerate(lines):
        if line.startswith(f"{target}: diagnosis:"):
            if SAME in line:
                return "same"
            following = lines[k + 1] if k + 1 < len(lines) else ""
            return "stated" if following.strip().startswith(DIFFERS) else "neither"
    return "neither"


def one_answer(config_path: Path, report) -> dict | None:
    """Per equation the diagnosis ``report`` (of the case at ``config_path``) names: what ``msam run``
    on the same case says (None where no equation is named)."""
    from msam_torch.run.adapt import adapt

    named = [g.target for g in report.equations if g.verdict_kind is Verdict.EXPLAINED]
    if not named:
        return None
    config = load_config(config_path)
    lines = agreement(adapt(config, base_dir=config_path.parent), report, config)
    found = {t: read_back(lines, t) for t in named}
    return {"equations": found, "agrees_or_states": all(v != "neither" for v in found.values()),
            "same": all(v == "same" for v in found.values())}
