"""Catalogue names of threshold hypotheses (:mod:`~msam_torch.diagnosis.effects.thresholds`), given only
within confidence: the threshold's bootstrap interval (:mod:`~msam_torch.diagnosis.effects.profile`)
at most :data:`HELD` of its signal's range, and for a hinge the total exponent on ``max(0, s - c)``
(``1 + gamma``) held as a power law's is (:func:`~msam_torch.diagnosis.catalogue.naming.half_width`)
and inside the entry's range. The entry's quantities are read as for a power law: what the
equation balances, and the quantity of the signal ``s`` (the thresholded term's and the dependency's)."""
from __future__ import annotations

from msam_torch.diagnosis.catalogue import entries as catalogue
from msam_torch.diagnosis.effects.hypotheses import Hypothesis
from msam_torch.model.spec import Equation, derivative_name, split_derivative

HELD = 0.1  # a threshold's interval half-width, at most this share of its signal's range, to be named


def reading(roles: catalogue.Roles, equation: Equation, h: Hypothesis) -> catalogue.Reading:
    """The threshold as the catalogue reads it: the state the equation balances and the signal's quantity."""
    base, order = split_derivative(equation.target)
    signal = h.threshold.signal
    return catalogue.Reading(roles.of(derivative_name(base, order - 1)), roles.of(signal), roles.of(signal), signal, 1.0)


def threshold_name(roles: catalogue.Roles, entries: tuple, equation: Equation, h: Hypothesis, gamma: float | None,
                   half: float | None, ok: bool) -> tuple[str, dict]:
    """The name of threshold hypothesis ``h`` (:data:`~msam_torch.diagnosis.catalogue.entries.NOT_CATALOGUED`
    if none) and what the report says of it; ``gamma``, ``half``: a hinge's fitted exponent and its
    interval's half-width (None otherwise); ``ok``: a valid fit whose exponent (if any) is held."""
    t = h.threshold
    read = reading(roles, equation, h)
    total = None if gamma is None else gamma + 1.0
    found = [e for e in catalogue.threshold_entries(entries, t.shape, read)
             if total is None or catalogue.holds(e, total, half)] if ok else []  # a clip's exponent is 1
    held = t.half_width <= HELD * t.span
    entry = catalogue.sole(found) if held else None
    measured = f"{t.text()} ± {t.half_width:.3g}" + ("" if total is None else f", total exponent {total:.2f} ± {half:.2f}")
    if entry is not None:
        text = f"{entry.name} ({entry.domain}): {measured}"
    elif not ok:
        text = f"threshold law, {measured}: not an effect (exponent out of range or unstable under the bootstrap)"
    elif not held:
        text = (f"threshold law, {measured}: the threshold is held to more than {100 * HELD:.0f} % of "
                f"{t.signal}'s range {t.span:.3g}")
    else:
        text = f"threshold law, {measured} (no catalogued effect{'s told apart' if found else ''})"
    return (catalogue.NOT_CATALOGUED if entry is None else entry.name), {
        "effect": None if entry is None else entry.name, "text": text, "total_exponent": total,
        "half_width": half, "on": t.signal, "consistent": [e.name for e in found],
        "catalogue_exponent": None if entry is None else catalogue.catalogue_exponent(entry),
        "domain": None if entry is None else entry.domain,
        "description": None if entry is None else entry.description,
        "reference": None if entry is None else entry.reference,
        "quantities": {"acts_on": read.acts_on, "term": read.term, "depends_on": read.depends_on},
        "assumed_quantities": dict(roles.assumed),
        "threshold": {"shape": t.shape, "signal": t.signal, "side": t.side, "value": t.value,
                      "half_width": t.half_width, "range": t.span}}
