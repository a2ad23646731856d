"""The adapted structure written as a starting model: the effect of each given equation put into
the config's ``model`` section, so that the next diagnosis of effects in turn (:mod:`.multi`)
starts from it (the adapted model, Eq. 9, becomes the new Eq. 2); and a provisional effect taken
out again (:func:`without`).

A multiplicative effect replaces its component ``M`` by ``M |f|^gamma`` (the component keeps its
adjustability); an additive one adds a fixed component ``theta' M |f|^gamma`` beside ``M``; every
theta becomes the adapted model's number in the data's units (the normalisation ``|f/s|^gamma``
folded back). A negative exponent reads ``(|f| + e)^gamma`` with ``e`` the floor the fit itself
used (:data:`~msam_torch.engine.candidates.FLOOR` of the function's scale), so that a Coulomb-type term
stays finite where ``f`` crosses zero.
"""
from __future__ import annotations

from msam_torch.config.schema import Config, load_config
from msam_torch.engine.candidates import FLOOR
from msam_torch.model.spec import Equation
from msam_torch.simulation.equations import EquationModel

ADAPTED = 2  # the adapted model's row in the batch of :func:`~msam_torch.diagnosis.compare.comparison.models`


def power_term(term: str, function, gamma: float, scale: float) -> str:
    """``M |f|^gamma`` (``M sign(f) |f|^gamma`` for a signed function) as an expression."""
    inner = function.inner_text if function.is_magnitude else function.text
    magnitude = f"abs({inner})" if gamma >= 0 else f"(abs({inner}) + {FLOOR * scale:.6g})"
    signed = "" if function.is_magnitude else f"*sign({inner})"
    factor = term if term.isidentifier() else f"({term})"
    return f"{factor}{signed}*{magnitude}**{gamma:.6g}"


def adapted_components(equation: Equation, model: EquationModel) -> list[dict]:
    """The components (config form) of the adapted row of ``model`` (its equation is the extended
    form of ``equation``: the starting components, then a copy of every adjustable one; the copies'
    and the adjustments' choices index ``equation.adjustments`` followed by the constants 1 and 0)."""
    extended = model.equation
    n_f = len(equation.adjustments)
    original = len(equation.components)
    choice, gamma = model.choice[ADAPTED].tolist(), model.gamma[ADAPTED].tolist()
    theta, theta_fixed = model.theta[ADAPTED], model.theta_fixed[ADAPTED].tolist()
    slots = {i: k for k, i in enumerate(extended.adjustable)}
    fixed = {i: k for k, i in enumerate(extended.fixed)}
    out, added = [], []
    for i, component in enumerate(extended.components):
        term = component.term.text
        if i in fixed:
            out.append({"term": term, "theta": theta_fixed[fixed[i]], "adjustable": False})
            continue
        k = slots[i]
        f = choice[k]
        if f == n_f + 1:  # a copy switched off
            continue
        value = float(theta[k]) if f == n_f else float(theta[k] * model.scale[f] ** (-gamma[k]))
        if f < n_f:
            term = power_term(term, equation.adjustments[f], gamma[k], float(model.scale[f]))
        entry = {"term": term, "theta": value}
        if i >= original:  # an additive copy: a component of its own, its law found
            added.append({**entry, "adjustable": False})
            continue
        source = equation.components[i]
        allowed = None if source.allowed is None else [equation.adjustments[a].text for a in source.allowed]
        out.append({**entry, "adjustable": source.adjustable, **({"adjustments": allowed} if allowed else {})})
    return out + added


def with_effects(config: Config, spec_equations: tuple[Equation, ...], models: dict[str, EquationModel]) -> Config:
    """``config`` whose equations named in ``models`` (target -> the equation's comparison batch)
    are their adapted structures; the other equations and sections unchanged."""
    raw = config.model_dump(mode="json", exclude_none=True)
    equations = raw["model"]["equations"]
    for e, equation in enumerate(spec_equations):
        if equation.target in models:
            equations[e]["components"] = adapted_components(equation, models[equation.target])
    return load_config(raw)



def without(config: Config, before: Config, provisional: Config) -> Config:
    """``config`` less the effects that ``provisional`` added to ``before`` (the configs share the
    component order of :func:`adapted_components`): a component it added is removed, and a
    component whose term it replaced, untouched since, gets back its term and nominal theta."""
    raw = config.model_dump(mode="json", exclude_none=True)
    for e, equation in enumerate(raw["model"]["equations"]):
        old = before.model.equations[e].components
        new = provisional.model.equations[e].components
        added = {c.term for c in new[len(old):]}
        components = [c for c in equation["components"] if c["term"] not in added]
        for i, (o, n) in enumerate(zip(old, new)):
            if o.term != n.term and components[i]["term"] == n.term:
                components[i].update(term=o.term, theta=o.theta)
        equation["components"] = components
    return load_config(raw)
