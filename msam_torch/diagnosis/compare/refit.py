"""Re-fits of an adapted equation for checks on a record: the unadjusted model with theta by
least squares, an entry held at another exponent with theta re-fitted, the one-step prediction of an
entry, the catalogue laws its exponents read as and the best-ranked rival with other laws, and the
relative error of an input predicted by solving the equation for it (EMPS: the motor force of the
inverse model)."""
from __future__ import annotations

from dataclasses import replace

import torch

from msam_torch.diagnosis.catalogue.entries import effect_entry
from msam_torch.engine.candidates import EquationData
from msam_torch.engine.step import lstsq
from msam_torch.run.result import EquationResult, adjusted_columns


def retuned_start(equation, data: EquationData) -> EquationResult:
    """The unadjusted model with theta by linear least squares (adjustable and fixed components)."""
    design = torch.cat([data.components, data.fixed_components], -1)[0]
    solution = lstsq(design, data.y[0])
    order = list(equation.adjustable) + list(equation.fixed)
    theta = [0.0] * len(equation.components)
    for k, i in enumerate(order):
        theta[i] = float(solution[k])
    none = [None] * len(equation.components)
    return EquationResult(equation.target, "", "", none, none, theta, {}, {}, [], 0)


def one_step(equation, entry, signals: dict) -> torch.Tensor:
    """The modelled derivative of an entry (adjustments, exponents, theta in data units): (N,)."""
    return adjusted_columns(equation, entry, signals) @ torch.as_tensor(entry.theta, dtype=signals[equation.target].dtype)


def named_laws(equation, entry, starting: torch.Tensor) -> list[tuple[int, str, float]]:
    """(component, catalogue name, the name's exponent) of each adjusted component of ``entry``
    whose exponent falls in a catalogue interval (msam_torch.diagnosis.catalogue.entries); the name's
    exponent is the catalogue's (Coulomb friction: gamma -1, the sign of the rate), or the fitted
    one for an entry with a range; ``starting``: the nominal theta (Q,), which says hardening or
    softening."""
    texts = [f.text for f in equation.adjustments]
    laws = []
    for i, (a, g) in enumerate(zip(entry.adjustments, entry.exponents)):
        if a is None:
            continue
        found, power = effect_entry(equation, i, texts.index(a), g, entry.theta[i], float(starting[i]))
        if found is not None:
            laws.append((i, found.name, g if isinstance(found.exponent, tuple) else found.exponent - power))
    return laws


def rival(equation, eq, starting: torch.Tensor) -> tuple[int, dict] | None:
    """The best-ranked candidate (rank, ranking row) whose catalogue names, at its round-robin
    exponents, differ from the winner's (names compared without hardening/softening, which needs
    each candidate's theta), or None."""
    base = lambda names: {name.replace("hardening ", "").replace("softening ", "") for name in names}
    laws = lambda entry: base(name for _, name, _ in named_laws(equation, entry, starting))
    winner = laws(eq)
    for rank, row in enumerate(eq.ranking[1:], start=1):  # rank 0 is the winner itself
        adjustments, exponents = [None] * len(equation.components), [None] * len(equation.components)
        for k, i in enumerate(equation.adjustable):  # ranking rows list the adjustable components only
            adjustments[i], exponents[i] = row["adjustments"][k], row["exponents"][k]
        if laws(replace(eq, adjustments=adjustments, exponents=exponents)) != winner:
            return rank, row
    return None


def retuned_at(equation, entry, signals: dict, component: int, exponent: float) -> EquationResult:
    """``entry`` with one exponent set to ``exponent`` and every theta re-estimated by linear least
    squares (the theta re-estimation of msam_torch.engine.tuning, on the same signals)."""
    exponents = list(entry.exponents)
    exponents[component] = exponent
    moved = replace(entry, exponents=exponents)
    theta = lstsq(adjusted_columns(equation, moved, signals), signals[equation.target])
    return replace(moved, theta=[float(v) for v in theta])


def errors(y, yhat) -> dict:
    eps = y - yhat
    return {"sum_abs": float(eps.abs().sum()), "rmse": float(eps.pow(2).mean().sqrt()),
            "rel": float(eps.norm() / y.norm())}


def force_error(equation, entry, signals: dict, input_name: str) -> float:
    """Relative error of the input predicted by solving the equation for its input term (EMPS:
    the motor force of the inverse model, as in the data README)."""
    k = [c.term.text for c in equation.components].index(input_name)
    tau = signals[input_name]
    tau_hat = tau + (signals[equation.target] - one_step(equation, entry, signals)) / entry.theta[k]
    return float((tau - tau_hat).norm() / tau.norm())
