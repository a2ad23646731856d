"""Config -> :class:`Plan`: every option that names a strategy interpreted once.

``data.derivatives``, ``adaptation.evaluation``, ``adaptation.step_size`` and ``adaptation.theta``
name strategies kept in registries (:mod:`msam_torch.config.registry`): derivative estimators
(:data:`~msam_torch.data.derivatives.ESTIMATORS`), evaluators (:data:`~msam_torch.run.evaluators.EVALUATORS`)
and step-size rules (:data:`~msam_torch.engine.step_rules.STEP_SIZES`; theta: :class:`~msam_torch.config.schema.ThetaRule`).
:func:`prepare` turns them into objects, once, in a frozen :class:`Plan` that ``adapt``, the trial
protocol and ``diagnose`` run from; nothing downstream reads those config keys again.

From Python, a strategy object serves as well as its name, in the config (``{"data":
{"derivatives": SavitzkyGolay(window=15)}}``) or as a keyword of :func:`prepare` and
:func:`msam_torch.run.adapt.adapt` (``adapt(config, data=frame, derivatives=SavitzkyGolay(window=15))``).

Measured data get safe settings (``adaptation.preset``, :data:`PRESETS`): where ``adapt`` reads
a file or a table rather than a simulation (:func:`records_measured`), the keys the config does
not give are filled from the ``measured`` preset: Eq. 6 in weak form where the sampling resolves
the band of the signals the regressors read (``adaptation.form: auto``, :mod:`msam_torch.engine.weak_form`:
the target integrated by parts against test functions of that band, every regressor filtered by
the same kernel, so a non-linearity's harmonics are filtered from both sides alike; derivatives
the regressors need through a zero-phase Butterworth filter above that band,
:mod:`msam_torch.run.estimation`), else on Butterworth derivatives at the noise floor; every
adjustment function normalised by its RMS (units, design.md 2.7); and theta re-solved at every step (variable projection, Eq. 17-18), so the
result does not hinge on the nominal theta. Where candidates are judged by simulation
(:data:`SIMULATED`), the step is a damped Gauss-Newton step in exponent units with a backtracking
line search: the simulated sensitivities of exponents on correlated states are nearly collinear,
and the undamped dM-scaled step with Eq. 20's mu leaves the exponents' range (docs/results/performance.md,
"Algebraic vs simulation-based evaluation"). ``preset: paper`` keeps the literal step. The
diagnosis always uses the weak form and its band-limited estimation; it is prepared without a
preset.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass

import torch

from msam_torch.config.schema import Config, validate
from msam_torch.config.to_spec import to_spec
from msam_torch.data.derivatives import ESTIMATORS, DerivativeEstimator
from msam_torch.data.loading import DataArgument, Dataset, derivative_estimator
from msam_torch.engine.step_rules import STEP_SIZES
from msam_torch.engine.trainer import Trainer
from msam_torch.engine.values import Evaluator, StepOptions, simulates
from msam_torch.errors import ConfigError
from msam_torch.model.spec import ModelSpec
from msam_torch.run.evaluators import EVALUATORS
from msam_torch.run.progress import LOGGER

SECTIONS = {"derivatives": "data", "evaluation": "adaptation", "step_size": "adaptation", "theta": "adaptation"}
PRESETS = {  # preset -> {(section, key): value} for the keys a config does not give
    "paper": {},
    "measured": {("data", "derivatives"): "butterworth", ("adaptation", "normalize"): "rms",
                 ("adaptation", "theta"): "varpro", ("adaptation", "form"): "auto"},
}
SIMULATED = {  # preset -> its further keys for models judged by simulation (adaptation.evaluation)
    "paper": {},
    "measured": {("adaptation", "scaling"): "gauss_newton", ("adaptation", "step_size"): "line_search",
                 ("adaptation", "damping"): 0.1},
}


@dataclass(frozen=True)
class Plan:
    """A validated config with its strategies as objects: the model ``spec``, the derivative
    estimator, the evaluator, the step ``options`` (step-size and theta rules, Eq. 15-20), and the
    dtype and device the tensors live on."""

    config: Config
    spec: ModelSpec
    derivatives: DerivativeEstimator
    evaluator: Evaluator
    options: StepOptions
    dtype: torch.dtype
    device: torch.device

    @property
    def simulates(self) -> bool:
        """The evaluator judges candidates by simulation (its ``simulates``; else algebraically)."""
        return simulates(self.evaluator)


def updated(config: Config, settings: dict, origin: str) -> Config:
    """``config`` with ``settings`` ``{(section, key): value}`` (``data`` and ``adaptation`` keys,
    objects kept), validated as a config is; keys it does not give stay unset, for the preset."""
    raw = {"model": config.model}
    for section in ("data", "adaptation"):
        given = getattr(config, section)
        raw[section] = {key: getattr(given, key) for key in given.model_fields_set}
    for (section, key), value in settings.items():
        raw[section][key] = value
    return validate(Config, raw, origin)


def with_strategies(config: Config, **strategies) -> Config:
    """``config`` with the strategy options given by keyword (``derivatives``, ``evaluation``,
    ``step_size``, ``theta``), each a name or a strategy object, validated as a config is."""
    unknown = sorted(set(strategies) - set(SECTIONS))
    if unknown:
        raise TypeError(f"unknown strategy option {', '.join(unknown)} (known: {', '.join(SECTIONS)})")
    return updated(config, {(SECTIONS[key], key): value for key, value in strategies.items()}, "strategy arguments")


def with_options(config: Config, **options) -> Config:
    """``config`` with keys of its ``data`` and ``adaptation`` sections given by name (``theta="varpro"``,
    ``refinement_steps=300``, ``preset="paper"``); an unknown name is a :class:`ConfigError` naming it."""
    sections = {key: section for section in ("data", "adaptation") for key in type(getattr(config, section)).model_fields}
    for key in options:
        if key not in sections:
            close = difflib.get_close_matches(key, list(sections), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(key, f"unknown option (the options are the keys of the config's data and adaptation "
                                   f"sections){hint}")
    return updated(config, {(sections[key], key): value for key, value in options.items()}, "options")


def records_measured(config: Config, data: DataArgument = None) -> bool:
    """Whether the training record is measured: a file or table (``data`` or ``data.file``), or a
    :class:`~msam_torch.data.loading.Dataset` holding measured signals; not a simulated system."""
    if isinstance(data, Dataset):
        return bool(data.measured)
    return data is not None or config.data.file is not None


def with_preset(config: Config, measured: bool, simulated: bool = False) -> Config:
    """``config`` with the keys it does not give filled from its ``adaptation.preset``
    (``auto``: ``measured`` for measured records, else ``paper``); ``simulated``: its candidates
    are judged by simulation (:data:`SIMULATED`)."""
    name = config.adaptation.preset
    if name == "auto":
        name = "measured" if measured else "paper"
    if name not in PRESETS:
        raise ConfigError("adaptation.preset", f"unknown preset {name!r} (choose from auto, {', '.join(PRESETS)})")
    given = {"data": config.data.model_fields_set, "adaptation": config.adaptation.model_fields_set}
    preset = {**PRESETS[name], **(SIMULATED[name] if simulated else {})}
    settings = {(section, key): value for (section, key), value in preset.items() if key not in given[section]}
    if not settings:
        return config
    LOGGER.debug("preset %r: %s (adaptation.preset=paper keeps the paper's step)", name,
                ", ".join(f"{section}.{key}={value}" for (section, key), value in settings.items()))
    return updated(config, {**settings, ("adaptation", "preset"): name}, f"preset {name!r}")


def step_options(config: Config) -> StepOptions:
    """The step of Eq. 15-20 as configured: its step-size rule and theta rule, dgamma, scaling,
    damping and divergence limit."""
    a = config.adaptation
    return StepOptions(dgamma=a.dgamma, scaling=a.scaling, step_size=a.step_size, theta=a.theta,
                       damping=a.damping, gamma_limit=a.gamma_limit)


def prepare(config: Config, in_memory: bool = False, measured: bool = False, **strategies) -> Plan:
    """The :class:`Plan` of ``config`` (``strategies`` as in :func:`with_strategies`, then its preset
    for the keys neither gives, applied for ``measured`` records, see :func:`records_measured`);
    ``in_memory``: the measurements come from a table given in memory (``auto`` then estimates)."""
    if strategies:
        config = with_strategies(config, **strategies)
    evaluator = EVALUATORS.resolve(config.adaptation.evaluation)
    config = with_preset(config, measured, simulated=simulates(evaluator))
    a = config.adaptation
    return Plan(config, to_spec(config.model), derivative_estimator(config.data, in_memory),
                evaluator, step_options(config), getattr(torch, a.dtype), torch.device(a.device))


REGISTRIES = {r.kind: r for r in (ESTIMATORS, STEP_SIZES, EVALUATORS)}  # the registries config keys name


def config_schema() -> dict:
    """The JSON schema of a config, every key that names a strategy listing its registry's names."""
    schema = Config.model_json_schema()
    for section in schema["$defs"].values():
        for node in section.get("properties", {}).values():
            if "strategy" in node:
                node["enum"] = list(REGISTRIES[node["strategy"]].names)
    return schema


def make_trainer(plan: Plan, diagnostics: bool = False) -> Trainer:
    """The :class:`Trainer` of Algorithm 1 for ``plan`` (``diagnostics``: condition numbers too)."""
    a = plan.config.adaptation
    return Trainer(plan.options, a.round_robin_steps, a.refinement_steps, a.chunk_size, plan.evaluator, diagnostics)
