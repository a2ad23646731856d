"""Catalogue names of fitted hypotheses (:mod:`msam_torch.diagnosis.catalogue.entries`), given only within confidence
(docs/design.md section 3).

Each effect hypothesis's *total exponent* on its signal (``gamma`` plus the power of the signal in
its component: ``c v|v|^-0.3`` is 0.7 on ``v``) gets an interval from the bootstrap trials
(:mod:`msam_torch.diagnosis.effects.bootstrap`): the original fit +- two robust standard deviations (1.4826 median absolute
deviations, so that a trial falling into another optimum does not widen it) of the trials' exponents,
or of the exponents of copies of the record with its measured states' noise doubled where those
spread wider (a trial or copy that never left its warm start at the original fit has none of its
own), never narrower than the catalogue's resolution +-0.2 (neither sees the bias of the weak-form
estimate or of a smoothed law), plus how far the copies' median moved from the fit
(:func:`noise_shift`: noise in a regressor biases an exponent). An entry names it only when that
interval holds the catalogue's exponent and no other entry's (:func:`~msam_torch.diagnosis.catalogue.entries.match`); nothing is moved into an
interval. A hypothesis whose exponent leaves the sane range (:data:`~msam_torch.diagnosis.effects.hypotheses.SANE_EXPONENT`) or
never left its start (no step was accepted: the exponent is not estimated), or whose interval is
wider than :data:`STABLE_HALF_WIDTH` or rests on fewer than half the trials, is not an effect; nor
is a start of a form that ended within the interval of that form's best start (:func:`repeated`). The
offset hypothesis (a constant the equation lacks) has no exponent: it is named :data:`OFFSET`
whenever its fit is valid.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from msam_torch.diagnosis.catalogue import entries as catalogue
from msam_torch.diagnosis.compare.verdict import Verdict
from msam_torch.diagnosis.effects.bootstrap import Bootstrap
from msam_torch.diagnosis.effects.hypotheses import EXPONENTLESS, Fitted, Hypothesis, sane, slot
from msam_torch.model.spec import Equation, ModelSpec

STABLE_HALF_WIDTH = 1.0  # an exponent known no better than +-1 is not an effect
SPREAD = 2.0  # interval half-width in standard deviations of the trials' exponents
MAD_TO_STD = 1.4826  # median absolute deviation -> standard deviation of a normal distribution
OFFSET = "constant offset"
OFFSET_DESCRIPTION = ("a constant the equation lacks: an offset of a sensor or an actuator, or a constant load "
                      "(gravity, a preload, a bias current)")
OFFSET_REFERENCE = "Ljung, System Identification: Theory for the User, 2nd ed., Prentice Hall (1999), sec. 14.1"


@dataclass(frozen=True)
class Naming:
    """Per hypothesis (C): its name, whether it may be reported as an effect, and what the report
    says of it (None for the re-fitted start)."""

    names: list[str]
    admissible: torch.Tensor
    details: list[dict | None]
    loose: torch.Tensor  # (C,) not effects only because their exponent is held too loosely

    def catalogue_exponent(self, c: int) -> float | list[float] | None:
        return None if self.details[c] is None else self.details[c]["catalogue_exponent"]


def half_width(boot: Bootstrap | None, c: int, s: int, fitted: float) -> float:
    """Hypothesis ``c``'s exponent interval in slot ``s``, as a half-width about the original fit
    ``fitted``: two robust standard deviations of the exponents of the trials that re-fitted it, or
    of the copies with doubled noise (:mod:`msam_torch.diagnosis.effects.bootstrap`) where they spread wider, at least the
    catalogue's tolerance, plus how far the copies' median moved from the fit (:func:`noise_shift`);
    inf when fewer than half of the trials re-fitted it. Trials and copies are warm-started at the
    fit: one whose exponent never left it accepted no step and has no estimate of its own, and is
    left out, since it would shrink the spread (when fewer than two moved, no step near the fit
    improved it: the tolerance)."""
    if boot is None:
        return catalogue.TOLERANCE
    valid = ~boot.fitted.invalid[:, c] & torch.isfinite(boot.rmse[:, c])
    if 2 * int(valid.sum()) < valid.numel() or int(valid.sum()) < 2:
        return float("inf")
    trials = _moved(boot.fitted.gamma[:, c, s], valid, fitted)
    copies = _moved(boot.noisier.gamma[:, c, s], ~boot.noisier.invalid[:, c], fitted)
    spread = max((SPREAD * MAD_TO_STD * float((g - g.median()).abs().median()) for g in (trials, copies)
                  if g.numel() >= 2), default=0.0)
    return max(spread, catalogue.TOLERANCE) + noise_shift(copies, fitted)


def _moved(gamma: torch.Tensor, valid: torch.Tensor, fitted: float) -> torch.Tensor:
    return gamma[valid & (gamma != fitted)]


def noise_shift(copies: torch.Tensor, fitted: float) -> float:
    """How far doubling the measured states' noise moved an exponent from the original fit
    ``fitted``: the median of the ``copies`` that moved (:mod:`msam_torch.diagnosis.effects.bootstrap`). Noise in a regressor
    moves a non-linear law's exponent (errors in variables), and about as far again when its power
    is doubled, in a direction the interval must reach (0 with fewer than two copies)."""
    return abs(float(copies.median()) - fitted) if copies.numel() >= 2 else 0.0


def name_hypotheses(spec: ModelSpec, equation: Equation, hypotheses: list[Hypothesis], original: Fitted,
                    boot: Bootstrap | None, nominal: torch.Tensor) -> Naming:
    """Names, admissibility and report details of every hypothesis; ``nominal``: the starting
    theta (Q,), whose sign says hardening or softening."""
    roles = catalogue.Roles.of_equation(spec, equation)
    entries = catalogue.entries(spec)
    is_sane = sane(original)[0]
    names, admissible, details, loose = [], [], [], []
    for c, h in enumerate(hypotheses):
        if h.kind == "retuned":
            names.append(Verdict.NO_GAP.text()), admissible.append(True), details.append(None), loose.append(False)
            continue
        if h.kind == "offset":
            names.append(OFFSET), admissible.append(True), details.append(_offset_details(roles)), loose.append(False)
            continue
        s = slot(equation, h)
        reading = catalogue.read(roles, equation, h.component, h.function)
        gamma = float(original.gamma[0, c, s])
        total = gamma + (reading.power or 0.0)
        half = half_width(boot, c, s, gamma)
        estimated = bool(is_sane[c]) and gamma != h.start  # sane, and a step was accepted
        ok = estimated and half <= STABLE_HALF_WIDTH
        too_loose = estimated and STABLE_HALF_WIDTH < half < float("inf")
        same_sign = _same_sign(h, equation, original.theta[0, c], nominal)
        found = catalogue.consistent(entries, reading, total, half, same_sign) if ok or too_loose else []
        entry = catalogue.sole(found) if ok else None
        names.append(catalogue.NOT_CATALOGUED if entry is None else entry.name)
        admissible.append(ok), loose.append(too_loose)
        details.append(_details(entry, reading, roles, total, half, ok, [e.name for e in found], too_loose))
    device = original.gamma.device
    return Naming(names, torch.tensor(admissible, device=device), details, torch.tensor(loose, device=device))


def _details(entry, reading: catalogue.Reading, roles: catalogue.Roles, total: float, half: float, ok: bool,
             consistent: list[str], loose: bool) -> dict:
    """What the report says of one hypothesis's name (see :class:`~msam_torch.diagnosis.report.gap_report.EquationGap`);
    ``consistent``: the entries its interval holds (a name needs exactly one); ``loose``: not an
    effect only because its exponent is held too loosely."""
    on = reading.signal or "its adjustment"
    measured = f"exponent {total:.2f} ± {half:.2f} on {on}"
    if entry is not None:
        value = catalogue.catalogue_exponent(entry)
        text = f"{entry.name} ({entry.domain}): total {measured}, catalogue {value}"
    elif loose:
        within = f"; {' and '.join(consistent)} within" if consistent else ""
        text = f"power law, {measured} (held too loosely to name{within})"
    elif not ok:
        text = f"power law, {measured}: not an effect (exponent out of range or unstable under the bootstrap)"
    elif len(consistent) > 1:
        text = f"power law, {measured} (consistent with {' and '.join(consistent)}: not told apart)"
    elif reading.signal is None:
        text = f"power law, {measured} (no catalogued effect: the catalogue reads powers of one signal's magnitude, abs(s))"
    elif None in (reading.acts_on, reading.term, reading.depends_on):
        text = f"power law, {measured} (no catalogued effect: quantities not declared, see model.quantities)"
    else:
        text = f"power law, {measured} (no catalogued effect)"
    unit = roles.offset_scale(reading.signal)
    if entry is None and unit is not None:
        text += (f"; {reading.signal} is in {unit}, whose zero is not absolute: temperature laws (radiation, "
                 "T^4) read absolute temperature, so give it in kelvin to test them")
    return {"effect": None if entry is None else entry.name, "text": text, "total_exponent": total,
            "half_width": half, "on": reading.signal, "consistent": consistent,
            "catalogue_exponent": None if entry is None else catalogue.catalogue_exponent(entry),
            "domain": None if entry is None else entry.domain,
            "description": None if entry is None else entry.description,
            "reference": None if entry is None else entry.reference,
            "quantities": {"acts_on": reading.acts_on, "term": reading.term, "depends_on": reading.depends_on},
            "assumed_quantities": dict(roles.assumed)}


def _offset_details(roles: catalogue.Roles) -> dict:
    """What the report says of the offset hypothesis (the keys of :func:`_details`)."""
    return {"effect": OFFSET, "text": f"{OFFSET} (any domain): a fitted constant", "total_exponent": None,
            "half_width": None, "on": None, "consistent": [], "catalogue_exponent": None, "domain": "any", "description": OFFSET_DESCRIPTION,
            "reference": OFFSET_REFERENCE, "quantities": {"acts_on": None, "term": None, "depends_on": None},
            "assumed_quantities": dict(roles.assumed)}


def repeated(hypotheses: list[Hypothesis], named: Naming, rmse: torch.Tensor) -> torch.Tensor:
    """(C,) the starts of one form (kind, component, function) whose total exponent ended within
    the interval of the form's best admissible start (least held-out ``rmse`` (C,)): the same
    estimate again, from another start. Its own, narrower interval may hold no entry where the
    best start's holds one, so as a rival it would contest the name with itself, and a bootstrap
    trial it wins by a hair would count against it; it is neither."""
    out = torch.zeros(len(hypotheses), dtype=torch.bool, device=rmse.device)
    forms: dict[tuple, list[int]] = {}
    for c, h in enumerate(hypotheses):
        if h.kind not in EXPONENTLESS and bool(named.admissible[c]) and bool(torch.isfinite(rmse[c])):
            forms.setdefault(h.form, []).append(c)
    for starts in forms.values():
        best = min(starts, key=lambda c: float(rmse[c]))
        centre, half = named.details[best]["total_exponent"], named.details[best]["half_width"]
        for c in starts:
            out[c] = c != best and abs(named.details[c]["total_exponent"] - centre) <= half
    return out


@dataclass(frozen=True)
class Pinned:
    """An effect hypothesis held at a catalogue entry's exponent (theta re-fitted): a rival the
    name of another entry must be told apart from (:func:`~msam_torch.diagnosis.compare.confidence.summary`) even where the
    free fit of that hypothesis fell into another optimum."""

    hypothesis: int  # index into the hypotheses
    gamma: float  # the exponent in the hypothesis's slot: the entry's total exponent less the power of s in M
    entry: object  # the catalogue entry (EffectConfig)


def pinned(spec: ModelSpec, equation: Equation, hypotheses: list[Hypothesis]) -> list[Pinned]:
    """Every effect hypothesis (one per kind, component and function) at the exponent of each
    single-valued catalogue entry its quantities admit, other than the component's own law."""
    roles, entries, seen, out = catalogue.Roles.of_equation(spec, equation), catalogue.entries(spec), set(), []
    for c, h in enumerate(hypotheses):
        if h.kind in EXPONENTLESS or h.form in seen:
            continue
        seen.add(h.form)
        reading = catalogue.read(roles, equation, h.component, h.function)
        out += [Pinned(c, float(e.exponent) - reading.power, e) for e in catalogue.admitted(entries, reading)
                if not isinstance(e.exponent, tuple) and float(e.exponent) != reading.power]
    return out


def pinned_signs(pins: list[Pinned], hypotheses: list[Hypothesis], equation: Equation, theta: torch.Tensor,
                 nominal: torch.Tensor) -> list[bool]:
    """Whether each pinned fit (theta (P, 2Q)) has the sign its entry asks of the component."""
    return [catalogue.signed(p.entry, _same_sign(hypotheses[p.hypothesis], equation, theta[k], nominal))
            for k, p in enumerate(pins)]


def _same_sign(h: Hypothesis, equation: Equation, theta: torch.Tensor, nominal: torch.Tensor) -> bool:
    """An effect of the starting component's sign (always, for a multiplicative one); ``theta`` (2Q,)."""
    return h.kind == "multiplicative" or float(theta[slot(equation, h)]) * float(nominal[h.component]) > 0
