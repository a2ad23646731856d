"""YAML config -> validated, typed config; ``key=value`` overrides; the resolved config.

A config has three sections: ``model`` (the starting model, see :mod:`msam_torch.model.spec`), ``data``
(where the measurements come from) and ``adaptation`` (the MSAM options). Unknown keys, wrong
types, non-finite numbers, duplicated YAML keys, nesting deeper than :data:`MAX_YAML_DEPTH` and
malformed YAML raise :class:`~msam_torch.errors.ConfigError` naming the key path (and line).
Values are data: YAML is read with a ``yaml.SafeLoader`` and no string is ever executed.
"""
from __future__ import annotations

import enum
import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import pydantic
import yaml
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from msam_torch.config.registry import Strategy
from msam_torch.config.suggestions import misspelt
from msam_torch.errors import ConfigError

MAX_YAML_DEPTH = 64
_BRANCH = re.compile(r"^(str|int|float|bool|[a-z-]+\[.*[a-z].*\])$")  # pydantic's labels of union branches in a location


def _within_float64(value):
    try:
        finite = math.isfinite(float(value))
    except OverflowError:
        finite = False
    if not finite:
        raise ValueError("must be a finite number within float64")
    return value


def _not_boolean(value):
    if isinstance(value, bool):
        raise ValueError("must be a number, not a boolean")
    return value


Number = Annotated[Union[float, int], BeforeValidator(_not_boolean), AfterValidator(_within_float64)]



class ThetaRule(str, enum.Enum):
    """``adaptation.theta``: theta at its nominal value, or re-solved by linear least squares at
    every step (variable projection with Kaufman's Jacobian, design notes section 3). A member
    equals its config name."""

    FIXED = "fixed"
    VARPRO = "varpro"

    @property
    def re_solved(self) -> bool:
        return self is ThetaRule.VARPRO

class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ComponentConfig(_Section):
    """One component ``theta * M`` of a state equation (Eq. 2)."""

    term: str = Field(description="M_i: an expression of states, inputs and derivatives, e.g. 'x_dot'; a parameter "
                      "in it reads its nominal value (not re-fitted), e.g. 'T - Ta'")
    theta: Union[str, Number] = Field(description="nominal theta_i, a number or an expression of parameters")
    adjustable: bool = Field(True, description="whether MSAM may adjust this component (Eq. 8)")
    start: Optional[Number] = Field(None, description="starting exponent (default 0)")
    adjustments: Optional[list[str]] = Field(
        None, min_length=1, description="this component's adjustment functions, a subset of its equation's "
                                        "(default: all of them), e.g. a tank's outflow adjusted by its own level only")


class EquationConfig(_Section):
    """One state equation: its target derivative, components and adjustment set F."""

    target: str = Field(description="the derivative this equation models, e.g. x_ddot")
    components: list[ComponentConfig] = Field(min_length=1, description="the terms theta_i M_i of the equation (Eq. 2)")
    adjustments: list[str] = Field(min_length=1, description="adjustment functions f; abs(.) -> |f|^g, else sign(f)|f|^g")


QUANTITIES = ("position", "velocity", "acceleration", "angle", "angular_velocity", "angular_acceleration", "force",
              "torque", "current", "voltage", "charge", "magnetic_flux", "level", "volume", "flow", "pressure",
              "temperature", "temperature_difference", "heat_flow", "power", "concentration", "population", "dimensionless")


def _known_quantity(name: str) -> str:
    if name not in QUANTITIES:
        raise ValueError(f"unknown quantity {name!r} (known: {', '.join(QUANTITIES)})")
    return name


Quantity = Annotated[str, AfterValidator(_known_quantity)]
Quantities = Annotated[list[Quantity], BeforeValidator(lambda v: [v] if isinstance(v, str) else v), Field(min_length=1)]


class SignalQuantity(_Section):
    """What a signal is (the catalogue's roles come from it, docs/design.md section 3); units optional."""

    quantity: Quantity = Field(description="what the signal is: position, velocity, current, level, temperature, ...")
    unit: Optional[str] = Field(None, description="its unit, as the report's axes write it")


def _plain_quantity(value):
    """``x: position`` is ``x: {quantity: position}``."""
    return {"quantity": value} if isinstance(value, str) else value


class EffectConfig(_Section):
    """A catalogued physical effect ``theta' M |s|^gamma`` (msam_torch/diagnosis/catalogue/catalogue.yaml has the
    bundled ones in the same format)."""

    name: str = Field(min_length=1, description="the name a verdict gives the effect")
    domain: str = Field("user", description="the domain it belongs to (bundled: the catalogue's group)")
    acts_on: Quantities = Field(description="quantity (or quantities) whose balance the effect enters: the state "
                                            "whose derivative the equation gives, e.g. velocity for x_ddot")
    term: Quantities = Field(description="quantity of the component M the power law multiplies")
    depends_on: Quantities = Field(description="quantity of the signal s in |s|^gamma")
    form: Literal["additive", "multiplicative"] = Field(
        description="how the effect usually enters: beside its component, or replacing it (informational: the name "
                    "follows the total exponent)")
    exponent: Union[Number, tuple[Number, Number]] = Field(
        description="total exponent on the dependency (gamma plus the power of s in M), or a range [low, high]")
    sign: Literal["any", "same", "opposite"] = Field(
        "any", description="sign of the effect's theta relative to the starting component's")
    description: str = Field(min_length=1, description="one line of physics")
    reference: str = Field(min_length=1, description="where the law comes from")

    @model_validator(mode="after")
    def _ordered(self):
        if isinstance(self.exponent, tuple) and not self.exponent[0] < self.exponent[1]:
            raise ValueError(f"exponent range {list(self.exponent)} is not [low, high] with low < high")
        return self


class ModelConfig(_Section):
    """The starting model (Eq. 2): its signals, parameters and state equations."""

    states: list[str] = Field(min_length=1, description="state signals; derivatives are named by suffix (x_dot, x_ddot)")
    inputs: list[str] = Field([], description="input signals, read from the data")
    parameters: dict[str, Number] = Field({}, description="named nominal parameters the thetas are expressions of")
    equations: list[EquationConfig] = Field(min_length=1, description="one per modelled derivative")
    quantities: dict[str, Annotated[SignalQuantity, BeforeValidator(_plain_quantity)]] = Field(
        {}, description="signal (or parameter) -> quantity (position, velocity, angle, angular_velocity, current, voltage, level, "
                        "flow, temperature, concentration, population, ...) or {quantity, unit}; the catalogue's "
                        "roles come from these (a derivative of a declared position or angle is known)")
    effects: list[EffectConfig] = Field([], description="effects added to the bundled catalogue, in its format")


class RangeConfig(_Section):
    """A slice of the record, by time (default) or by sample index; bounds inclusive, open if null."""

    start: Optional[float] = Field(None, description="first time (or index) of the slice; null: the record's start")
    stop: Optional[float] = Field(None, description="last time (or index) of the slice; null: the record's end")
    by: Literal["time", "index"] = Field("time", description="whether start and stop are times or sample indices")


class DataConfig(_Section):
    """Where the measurements come from: a simulated controlled case or a measured data file."""

    system: Optional[str] = Field(None, description="name of a simulated system in msam_torch.data.systems "
                                  "(simulated once per machine, then read from the cache folder: MSAM_CACHE_DIR, "
                                  "empty for none, else the user cache folder)")
    file: Optional[str] = Field(None, description="CSV or Parquet file, relative to the config file")
    validation_file: Optional[str] = Field(None, description="held-out record (default: the validation range of 'file')")
    time: Optional[str] = Field(None, description="time column (or give sample_time)")
    sample_time: Optional[float] = Field(None, gt=0, description="sampling period when there is no time column")
    time_unit: Optional[str] = Field(None, description="the unit of time (of the time column or sample_time), as the "
                                     "report's axes and text write it, e.g. s; null: 'time unit'")
    columns: dict[str, str] = Field({}, description="signal name -> column name, for every measured signal")
    train: RangeConfig = Field(RangeConfig(), description="the slice of the record fitted")
    validation: Optional[RangeConfig] = Field(None, description="a held-out slice of the same record (or give validation_file)")
    parametric_error: float = Field(0.0, ge=0, description="total relative error of the nominal parameters")
    noise: float = Field(0.0, ge=0, description="simulated measurement noise, as a fraction of each signal's std")
    seed: int = Field(0, ge=0, lt=2**64, description="random seed (0 <= seed < 2**64)")
    derivatives: Annotated[Any, Strategy("derivative estimator")] = Field(
        "auto", description="how unmeasured derivatives are estimated: a name in msam_torch.data.derivatives.ESTIMATORS "
                            "or, from Python, an estimator object; 'auto': exact for a noise-free simulated system, "
                            "else savgol; 'exact': every signal the model reads is given")
    window: Optional[int] = Field(None, ge=3, description="derivative estimator window in samples "
                                                          "(default: chosen from the noise floor)")
    cutoff: Optional[float] = Field(None, gt=0, description="butterworth cut-off frequency in cycles per time unit "
                                                            "(Hz for seconds; default: the noise floor)")
    resample: bool = Field(False, description="interpolate irregularly sampled data onto a uniform grid")
    input_hold: Literal["auto", "zoh", "linear"] = Field(
        "auto", description="inputs between samples, for the weak form: zoh (held until the next sample, as a "
                            "digital-to-analog converter does), linear, or auto (zoh for an input that changes at "
                            "no more than half of its samples)")


class SimulationConfig(_Section):
    """Simulation-based evaluation (paper section 2): candidates are simulated with torchdiffeq and
    compared with the measured outputs (see :mod:`msam_torch.simulation`)."""

    output: list[str] = Field([], description="measured states compared with the simulation, e.g. [x2]")
    coupling: Literal["joint", "separate"] = Field(
        "joint", description="simulate all equations together, or adapt each with the other states read from the data")
    method: Literal["rk4", "midpoint", "euler"] = Field("rk4", description="fixed-step torchdiffeq solver")
    substeps: int = Field(1, ge=1, description="solver steps per sample interval")
    input_hold: Literal["linear", "zoh", "cubic"] = Field(
        "linear", description="inputs between samples: linear, zero-order hold, or cubic spline (band-limited inputs)")
    initial: Literal["estimate", "data"] = Field(
        "estimate", description="initial states estimated by least squares, or taken from the data / initial_guess")
    initial_guess: dict[str, Number] = Field({}, description="initial values of states the data do not give")
    prefit_steps: int = Field(15, ge=0, description="Levenberg-Marquardt steps fitting theta and initial states first")
    refit_steps: int = Field(0, ge=0, description="Levenberg-Marquardt steps on theta and initial states before every exponent step")
    saturation: dict[str, tuple[Optional[Number], Optional[Number]]] = Field(
        {}, description="range [low, high] of a simulated state (null: unbounded), e.g. {x2: [null, 10]}: the state "
                        "stops at a limit while its rate points beyond it (a tank that overflows, a level or sensor "
                        "that saturates) and the compared output is clipped to it")


class AdaptationConfig(_Section):
    """Options of Algorithm 1 and the step (Eq. 16-20)."""

    round_robin_steps: int = Field(15, ge=1, description="I1")
    refinement_steps: int = Field(70, ge=0, description="I2")
    dgamma: float = Field(1e-2, gt=0, description="exponent perturbation of Eq. 15-16")
    scaling: Literal["dm", "gauss_newton"] = Field("dm", description="step in dM-scaled units (Eq. 16-18) or in exponent units")
    step_size: Annotated[Any, Strategy("step-size rule")] = Field(
        "eq20", description="mu by Eq. 20, mu = 1, or backtracking (msam_torch.engine.step_rules.STEP_SIZES, or a rule object)")
    theta: ThetaRule = Field(ThetaRule.FIXED, description="nominal theta, or re-solved each step (variable projection)")
    normalize: Literal["none", "rms"] = Field("none", description="divide each adjustment function by its RMS")
    form: Literal["strong", "weak", "auto"] = Field(
        "strong", description="Eq. 6 on estimated derivatives (strong), or integrated against test functions of the "
                              "regressors' band (weak: no derivative of the target is estimated, and both sides are "
                              "filtered alike); auto: weak where the sampling resolves that band")
    preset: str = Field("auto", description="settings for the keys not given (msam_torch.run.plan.PRESETS): 'measured' "
                        "(butterworth derivatives, rms, varpro, form auto), 'paper' (the literal step), 'auto': measured for files and tables")
    tune_theta: bool = Field(False, description="start from theta re-estimated by least squares on the starting model")
    hold_fixed: bool = Field(False, description="theta re-estimation keeps the fixed components' theta at nominal")
    damping: float = Field(0.0, ge=0, description="Levenberg-Marquardt damping of the step")
    gamma_limit: float = Field(20.0, gt=0, description="|gamma| beyond which a candidate is marked diverged")
    chunk_size: int = Field(4096, ge=1, description="candidates per batched chunk (bounds memory)")
    dtype: Literal["float64", "float32"] = Field("float64", description="floating-point type of every tensor")
    device: str = Field("cpu", description="torch device, one the installed torch can use ('cpu', 'cuda', 'cuda:1')")
    evaluation: Annotated[Any, Strategy("evaluator")] = Field(
        "algebraic", description="candidate outputs from estimated states (Eq. 6) or by simulation "
                                 "(msam_torch.run.evaluators.EVALUATORS, or an evaluator object)")
    simulation: SimulationConfig = Field(SimulationConfig(), description="options of simulation-based evaluation")

    @field_validator("device")
    @classmethod
    def _usable_device(cls, value: str) -> str:
        """The device exists in this torch build and holds a tensor."""
        import torch

        try:
            torch.zeros(1, device=torch.device(value)).sum().item()
        except Exception as exc:  # torch raises RuntimeError, AssertionError, ... per backend
            reason = " ".join(str(exc).split()[:12]) or type(exc).__name__
            raise ValueError(f"{value!r} cannot be used by this torch {torch.__version__} ({reason})") from None
        return value


class Config(_Section):
    model: ModelConfig
    data: DataConfig = DataConfig()
    adaptation: AdaptationConfig = AdaptationConfig()

    @model_validator(mode="after")
    def _initial_guess_of_states(self):
        """``adaptation.simulation.initial_guess`` names states of the model."""
        for name in self.adaptation.simulation.initial_guess:
            if name not in self.model.states:
                raise ConfigError(f"adaptation.simulation.initial_guess.{name}",
                                  f"{name!r} is not a state of the model ({', '.join(self.model.states)})")
        return self


class Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that rejects a key given twice in one mapping and nesting deeper than
    :data:`MAX_YAML_DEPTH` (which would otherwise end in a ``RecursionError``)."""

    depth = 0

    def compose_node(self, parent, index):
        self.depth += 1
        try:
            if self.depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels",
                                                  self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                duplicated = key in seen
            except TypeError:  # unhashable: the base class says so
                continue
            if duplicated:
                raise yaml.constructor.ConstructorError(None, None, f"duplicated key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def load_yaml(text: str):
    """Parse YAML ``text`` with :class:`Loader`."""
    return yaml.load(text, Loader=Loader)


def read_yaml(path: Union[str, Path], what: str = "config") -> dict:
    """A YAML mapping from ``path``; unreadable or malformed files raise :class:`ConfigError`."""
    path = Path(path)
    try:
        raw = load_yaml(path.read_text())
    except FileNotFoundError:
        raise ConfigError("", f"{path}: no such {what} file") from None
    except yaml.YAMLError as exc:
        raise ConfigError("", f"{path}: malformed YAML{_yaml_place(exc)}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError("", f"{path}: cannot read the {what}: {exc}") from None
    if not isinstance(raw, dict):
        raise ConfigError("", f"{path}: the top level must be a mapping")
    return raw


def validate(schema: type[BaseModel], raw: dict, origin: str, overrides: tuple[str, ...] = ()):
    """``schema.model_validate(raw)``; the first problem raises :class:`ConfigError` with its key path
    (a value's own check, such as finiteness, is preferred to the type mismatches of a union's
    other branches, whose names are left out of the path) and where it was given: the
    command-line override that set it (or a section above it), else ``origin``."""
    try:
        return schema.model_validate(raw)
    except pydantic.ValidationError as exc:
        errors = exc.errors()
        error = next((e for e in errors if e["type"] == "value_error"), errors[0])
        loc = [p for p in error["loc"] if not (isinstance(p, str) and _BRANCH.match(p))]
        key = ".".join(f"[{p}]" if isinstance(p, int) else str(p) for p in loc).replace(".[", "[")
        dotted = lambda k: _INDEX.sub(r".\1", k)
        given = [o for o in overrides if (dotted(key) + ".").startswith(dotted(o.partition("=")[0]) + ".")]
        where = f"command-line override {given[-1]!r}" if given else f"in {origin}"
        raise ConfigError(key, f"{error['msg'].removeprefix('Value error, ')}{misspelt(error, errors, schema)} "
                               f"({where})") from None


def load_config(source: Union[str, Path, dict], overrides: list[str] = ()) -> Config:
    """Read a YAML file (or a dict), apply ``key.path=value`` overrides, validate."""
    if isinstance(source, dict):
        raw, origin = source, "config"
    else:
        raw, origin = read_yaml(source), str(source)
    return validate(Config, _apply_overrides(raw, overrides), origin, tuple(overrides))


def _yaml_place(exc: yaml.YAMLError) -> str:
    """`` at line L, column C: problem`` from a YAML error, on one line."""
    mark = getattr(exc, "problem_mark", None)
    place = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"{place}: {problem}"


_INDEX = re.compile(r"\[(\d+)\]")


def _apply_overrides(raw: dict, overrides) -> dict:
    """``key.path=value`` overrides (YAML values); ``[i]`` or ``.i`` indexes a list that exists
    (``model.equations[0].components[1].theta=-2``)."""
    import copy

    raw = copy.deepcopy(raw)
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(item, "an override must look like key.path=value")
        node = raw
        parts = _INDEX.sub(r".\1", key).split(".")
        for k, part in enumerate(parts):
            place = ".".join(parts[:k + 1])
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise ConfigError(key, f"{place!r}: the list has {len(node)} items (index 0 to {len(node) - 1})")
                part = int(part)
            elif not isinstance(node, dict):
                raise ConfigError(key, f"{'.'.join(parts[:k])!r} is not a section")
            if k == len(parts) - 1:
                break
            node = node[part] if isinstance(node, list) else node.setdefault(part, {})
        try:
            node[part] = load_yaml(value)
        except yaml.YAMLError as exc:
            raise ConfigError(key, f"malformed value {value!r}{_yaml_place(exc)}") from None
    return raw


def dump_config(config: Config) -> str:
    """The fully resolved config as YAML (defaults filled in)."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
