"""The effect catalogue (docs/design.md section 3): physical effects as data (``catalogue.yaml`` in this
package, plus a config's ``model.effects``), and the roles of a model's signals.

An effect term is ``theta' * M * |s|^gamma`` in the equation of a state's derivative. Its *total
exponent* on ``s`` is ``gamma`` plus the power of ``s`` in ``M`` (``v|v|^-1``: 0, Coulomb friction;
``c v|v|^-0.3``: 0.7). An entry fits when the quantities agree (what the equation balances, what
``M`` is, what ``s`` is) and the total exponent is in reach (:func:`match`). Quantities come from
the config's ``model.quantities``; a derivative of a declared position or angle (or charge, volume)
is known. Undeclared signals have no quantity, except in a second-order equation whose signals are
all undeclared: there the state is *assumed* a position and its rate a velocity, and the report
says so. Names never come from variable names.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass, field
from functools import cache
from importlib.resources import files

import yaml
from pydantic import BaseModel, ConfigDict

from msam_torch.config.schema import QUANTITIES, EffectConfig, validate
from msam_torch.diagnosis.effects.hypotheses import holds_constant
from msam_torch.model.expressions import Expression
from msam_torch.model.spec import Equation, ModelSpec, derivative_name, split_derivative

NOT_CATALOGUED = "power law, no catalogued effect"
TOLERANCE = 0.2  # the catalogue's resolution: the least half-width of an exponent interval
RATE_OF = {"position": "velocity", "velocity": "acceleration", "angle": "angular_velocity",
           "angular_velocity": "angular_acceleration", "charge": "current", "volume": "flow"}
ASSUMED = {0: "position", 1: "velocity"}
# quantities whose difference (of two signals) the catalogue reads as the quantity itself
READ_AS_ITSELF = ("position", "velocity", "angle", "angular_velocity", "level", "pressure", "voltage", "current")  # second-order equations with nothing declared
# temperature scales whose zero is not absolute zero (a declared unit, lower case, spaces dropped)
OFFSET_SCALES = {"c", "°c", "degc", "celsius", "degreesc", "degreecelsius", "degreescelsius",
                 "f", "°f", "degf", "fahrenheit", "degreesf", "degreefahrenheit", "degreesfahrenheit"}


class _CatalogueFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    domains: dict[str, list[EffectConfig]]


@cache
def bundled() -> tuple[EffectConfig, ...]:
    """The package's catalogue, each entry with the domain it is listed under."""
    raw = yaml.safe_load(files(__package__).joinpath("catalogue.yaml").read_text())
    parsed = validate(_CatalogueFile, raw, "msam_torch/diagnosis/catalogue/catalogue.yaml")
    return tuple(e.model_copy(update={"domain": d}) for d, entries in parsed.domains.items() for e in entries)


def entries(spec: ModelSpec | None = None) -> tuple[EffectConfig, ...]:
    """The bundled catalogue and the config's own effects."""
    return bundled() + (spec.effects if spec is not None else ())


def catalogue_exponent(entry: EffectConfig) -> float | list[float]:
    return list(entry.exponent) if isinstance(entry.exponent, tuple) else float(entry.exponent)


@dataclass(frozen=True)
class Roles:
    """The quantity of each signal of one equation, and those assumed rather than declared."""

    quantities: dict
    assumed: dict
    units: dict = field(default_factory=dict)  # declared units

    def of(self, signal: str) -> str | None:
        return self.quantities.get(signal)

    def of_expression(self, node: ast.AST) -> str | None:
        """The quantity of a signal, or of the difference ``a - b`` of two signals of one quantity
        ``q``: ``q_difference`` where that is a quantity (``T - Ta``: a temperature difference, which
        radiation's ``T^4`` does not read), else ``q`` itself for a quantity whose laws read a
        difference as they read the signal (:data:`READ_AS_ITSELF`: a spring between two bodies
        reads their relative displacement, a pipe between two tanks their level difference)."""
        if isinstance(node, ast.Name):
            return self.of(node.id)
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Sub) and \
                isinstance(node.left, ast.Name) and isinstance(node.right, ast.Name):
            q = self.of(node.left.id)
            if q is None or q != self.of(node.right.id):
                return None
            return f"{q}_difference" if f"{q}_difference" in QUANTITIES else q if q in READ_AS_ITSELF else None
        return None

    def offset_scale(self, signal: str | None) -> str | None:
        """The declared unit of a temperature ``signal`` whose zero is not absolute (degC, degF):
        a power of it is no power of the temperature that radiation and other laws read."""
        unit = self.units.get(signal) if signal is not None else None
        return unit if unit is not None and unit.lower().replace(" ", "") in OFFSET_SCALES \
            and self.of(signal) == "temperature" else None

    def exchanging(self, equation: Equation, nominal) -> dict[int, tuple[str, ...]]:
        """Adjustable components that are a signal exchanging with another signal of the same
        declared quantity in the same equation, their starting thetas of opposite signs (the
        ``T`` of ``-h (T - Ta)``), each with the signals it exchanges with (its references);
        ``nominal``: the starting thetas. None in an equation that holds a constant component:
        it carries the exchange's constant already."""
        if holds_constant(equation):
            return {}
        plain = {i: c.term.text for i, c in enumerate(equation.components) if c.term.text in self.quantities}
        partners = {i: tuple(s for j, s in plain.items() if j != i and self.of(s) == self.of(plain[i])
                             and float(nominal[i]) * float(nominal[j]) < 0)
                    for i in equation.adjustable if i in plain}
        return {i: references for i, references in partners.items() if references}

    @classmethod
    def of_equation(cls, spec: ModelSpec | None, equation: Equation) -> "Roles":
        declared = dict(spec.quantities) if spec is not None else {}
        known = dict(declared)
        base, order = split_derivative(equation.target)
        state = derivative_name(base, order - 1)  # what the effect acts on (:func:`read`), read or not
        for name in sorted(equation.signals | {equation.target, state}):
            root, times = split_derivative(name)
            q = declared.get(root)
            for _ in range(times):
                q = RATE_OF.get(q) if q is not None else None
            if name not in known and q is not None:
                known[name] = q
        assumed = {}
        if order == 2 and not any(s in declared for s in equation.signals):
            assumed = {derivative_name(base, k): q for k, q in ASSUMED.items()}
        return cls({**known, **assumed}, assumed, dict(spec.units) if spec is not None else {})


def power_in(term: Expression, signal: str) -> float | None:
    """The power of ``signal`` (a name, or an expression's text as :func:`ast.unparse` writes it) in
    the component ``term``: 1 (the signal itself), 0 (absent), else None."""
    if ast.unparse(term.tree) == signal:
        return 1.0
    return 0.0 if signal not in term.names else None


@dataclass(frozen=True)
class Reading:
    """How an effect hypothesis reads in the catalogue's terms: the quantities it involves, the
    signal ``s`` and the power of ``s`` in ``M`` (None: no catalogue entry can fit)."""

    acts_on: str | None
    term: str | None
    depends_on: str | None
    signal: str | None
    power: float | None


def read(roles: Roles, equation: Equation, component: int, function: int) -> Reading:
    f = equation.adjustments[function]
    base, order = split_derivative(equation.target)
    state = derivative_name(base, order - 1)
    term = equation.components[component].term
    inner = f.tree.args[0] if f.is_magnitude else None
    signal = f.inner_text if inner is not None and (f.inner_text.isidentifier() or roles.of_expression(inner)) else None
    power = power_in(term, signal) if signal is not None else None
    return Reading(roles.of(state), roles.of_expression(term.tree), roles.of_expression(inner) if signal else None,
                   signal, power)


def consistent(catalogue: tuple[EffectConfig, ...], reading: Reading, total: float, half_width: float,
               same_sign: bool) -> list[EffectConfig]:
    """The entries a total exponent ``total`` +- ``half_width`` is consistent with.

    Among entries whose quantities fit: a single-valued exponent inside the interval, a range
    holding ``total`` itself. An effect whose component and dependency are the same quantity acts
    through one signal: ``s`` must be ``M`` (``h1 |h2|^0.5`` is no outflow law of either level).
    A fit whose interval holds ``gamma = 0`` (the component's own law, unchanged) is consistent
    with none."""
    if reading.power is not None and abs(total - reading.power) <= half_width:
        return []
    fits = [e for e in admitted(catalogue, reading) if signed(e, same_sign)]
    inside = lambda e: (e.exponent[0] <= total <= e.exponent[1] if isinstance(e.exponent, tuple)
                        else abs(e.exponent - total) <= half_width)
    return list({e.name: e for e in fits if inside(e)}.values())


def admitted(catalogue: tuple[EffectConfig, ...], reading: Reading) -> list[EffectConfig]:
    """The entries whose quantities fit ``reading``, at any exponent and sign (see :func:`consistent`);
    a config's own entry shadows a bundled one of the same law (exponent and sign) that fits too:
    the config's name for it, not a tie no data can break."""
    if reading.power is None or None in (reading.acts_on, reading.term, reading.depends_on):
        return []
    if reading.term == reading.depends_on and reading.power != 1.0:
        return []
    fits = [e for e in catalogue if reading.acts_on in e.acts_on and reading.term in e.term
            and reading.depends_on in e.depends_on]
    own = [e for e in fits if e not in bundled()]
    return [e for e in fits if e in own or not any((e.exponent, e.sign) == (o.exponent, o.sign) for o in own)]


def signed(entry: EffectConfig, same_sign: bool) -> bool:
    """Whether an effect of the starting component's sign (``same_sign``) or the opposite fits ``entry``."""
    return entry.sign in ("any", "same" if same_sign else "opposite")


def match(catalogue: tuple[EffectConfig, ...], reading: Reading, total: float, half_width: float,
          same_sign: bool) -> EffectConfig | None:
    """The entry a total exponent ``total`` +- ``half_width`` names: the only one it is
    :func:`consistent` with; None when it is consistent with none or with several (an interval
    that holds two effects does not tell them apart)."""
    return sole(consistent(catalogue, reading, total, half_width, same_sign))


def sole(found: list[EffectConfig]) -> EffectConfig | None:
    """The entry that names a fit consistent with ``found``: the only one, else None."""
    return found[0] if len(found) == 1 else None


def effect_entry(equation: Equation, component: int, function: int, gamma: float, theta: float,
                 starting_theta: float, spec: ModelSpec | None = None,
                 half_width: float = TOLERANCE) -> tuple[EffectConfig | None, float | None]:
    """The entry naming ``theta * M_component * f_function^gamma`` read with ``spec``'s quantities
    (none: assumed only where :class:`Roles` says), and the power of ``s`` in ``M``."""
    reading = read(Roles.of_equation(spec, equation), equation, component, function)
    if reading.power is None:
        return None, None
    return match(entries(spec), reading, gamma + reading.power, half_width, theta * starting_theta > 0), reading.power


def name_effect(*args, **kwargs) -> str:
    """The name of :func:`effect_entry`'s entry, or :data:`NOT_CATALOGUED`."""
    entry, _ = effect_entry(*args, **kwargs)
    return NOT_CATALOGUED if entry is None else entry.name
