"""The starting model built from its config: ``to_spec(config.model)`` checks every name and
expression of the ``model`` section (each error names its key) and returns the
:class:`~msam_torch.model.spec.ModelSpec` (the paper's Eq. 2)."""
from __future__ import annotations

from msam_torch.config.schema import ModelConfig
from msam_torch.errors import ConfigError
from msam_torch.model.expressions import parse
from msam_torch.model.spec import Component, Equation, ModelSpec, derivative_name, split_derivative


def to_spec(config: ModelConfig) -> ModelSpec:
    """The :class:`ModelSpec` of a validated ``model`` section."""
    names = list(config.states) + list(config.inputs)
    seen = set()
    for i, name in enumerate(names):
        key = f"model.states[{i}]" if i < len(config.states) else f"model.inputs[{i - len(config.states)}]"
        if not name.isidentifier() or name == "t":
            raise ConfigError(key, f"{name!r} is not a valid signal name")
        if name in seen:
            raise ConfigError(key, f"{name!r} is listed twice")
        seen.add(name)
    signals = {"t"} | {derivative_name(split_derivative(n)[0], k) for n in names for k in range(3)}
    signals |= set(names)
    parameters = set(config.parameters)
    if parameters & signals:
        raise ConfigError("model.parameters", f"names shared with signals: {sorted(parameters & signals)}")
    nominal = dict(config.parameters)  # a parameter in a term or an adjustment reads its nominal value
    equations = []
    targets = set()
    for e, eq in enumerate(config.equations):
        key = f"model.equations[{e}]"
        base, order = split_derivative(eq.target)
        if eq.target not in signals or order == 0 or derivative_name(base, order - 1) not in config.states:
            raise ConfigError(f"{key}.target", f"{eq.target!r} is not the derivative of a state "
                              f"(states: {', '.join(config.states) or 'none'})")
        if eq.target in targets:
            raise ConfigError(f"{key}.target", f"{eq.target!r} has two equations")
        targets.add(eq.target)
        adjustments = tuple(
            parse(f, f"{key}.adjustments[{i}]", signals - {eq.target}, nominal) for i, f in enumerate(eq.adjustments)
        )
        if len({f.text for f in adjustments}) != len(adjustments):
            raise ConfigError(f"{key}.adjustments", "an adjustment function is listed twice")
        texts = [f.text for f in adjustments]

        def allowed(c, i):  # the component's subset of the equation's adjustment functions
            if c.adjustments is None:
                return None
            indices = []
            for j, f in enumerate(c.adjustments):
                where = f"{key}.components[{i}].adjustments[{j}]"
                text = parse(f, where, signals - {eq.target}, nominal).text
                if text not in texts:
                    raise ConfigError(where, f"{f!r} is not one of the equation's adjustments {texts}")
                indices.append(texts.index(text))
            if len(set(indices)) != len(indices):
                raise ConfigError(f"{key}.components[{i}].adjustments", "an adjustment function is listed twice")
            return tuple(indices)

        components = tuple(
            Component(
                term=parse(c.term, f"{key}.components[{i}].term", signals - {eq.target}, nominal),
                theta=parse(c.theta, f"{key}.components[{i}].theta", parameters),
                adjustable=c.adjustable,
                start=float(c.start or 0.0),
                allowed=allowed(c, i),
            )
            for i, c in enumerate(eq.components)
        )
        if not any(c.adjustable for c in components):
            raise ConfigError(f"{key}.components", "no component is adjustable: mark at least one adjustable "
                              "(an identity such as d_dot = v1 - v2 is then checked like any equation and "
                              "reads 'no significant gap' where it holds)")
        equations.append(Equation(eq.target, components, adjustments))
    for name in config.quantities:
        if name not in (signals - {"t"}) | parameters:
            raise ConfigError(f"model.quantities.{name}", f"{name!r} is not a state, an input, a derivative of one "
                              "or a parameter")
    quantities = {name: q.quantity for name, q in config.quantities.items()}
    units = {name: q.unit for name, q in config.quantities.items() if q.unit}
    return ModelSpec(tuple(config.states), tuple(config.inputs), dict(config.parameters), tuple(equations),
               quantities=quantities, units=units, effects=tuple(config.effects))
