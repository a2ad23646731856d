"""Config -> :class:`Plan`: every option that names a strategy interpreted once.

``data.derivatives``, ``adaptation.evaluation``, ``adaptation.step_size`` and ``adaptation.theta``
name strategies kept in registries (:mod:`msam_torch.registry`): derivative estimators
(:data:`~msam_torch.derivatives.ESTIMATORS`), evaluators (:data:`~msam_torch.evaluators.EVALUATORS`)
and step-size rules (:data:`~msam_torch.step_rules.STEP_SIZES`; theta: :class:`~msam_torch.step_rules.ThetaRule`).
:func:`prepare` turns them into objects, once, in a frozen :class:`Plan` that ``adapt``, the trial
protocol and ``diagnose`` run from; nothing downstream reads those config keys again.

From Python, a strategy object serves as well as its name, in the config (``{"data":
{"derivatives": SavitzkyGolay(window=15)}}``) or as a keyword of :func:`prepare` and
:func:`msam_torch.api.adapt` (``adapt(config, data=frame, derivatives=SavitzkyGolay(window=15))``).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .config import Config, validate
from .data import derivative_estimator
from .derivatives import DerivativeEstimator
from .evaluators import EVALUATORS, Evaluator
from .spec import ModelSpec
from .step import StepOptions
from .trainer import Trainer

SECTIONS = {"derivatives": "data", "evaluation": "adaptation", "step_size": "adaptation", "theta": "adaptation"}


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


def with_strategies(config: Config, **strategies) -> Config:
    """``config`` with the strategy options given by keyword (``derivatives``, ``evaluation``,
    ``step_size``, ``theta``), each a name or a strategy object, validated as a config is."""
    unknown = sorted(set(strategies) - set(SECTIONS))
    if unknown:
        raise TypeError(f"unknown strategy option {', '.join(unknown)} (known: {', '.join(SECTIONS)})")
    raw = {section: dict(getattr(config, section)) for section in type(config).model_fields}  # objects kept
    for key, value in strategies.items():
        raw[SECTIONS[key]][key] = value
    return validate(Config, raw, "strategy arguments")


def step_options(config: Config) -> StepOptions:
    """The step of Eq. 15-20 as configured: its step-size rule and theta rule, dgamma, scaling,
    damping and divergence limit."""
    a = config.adaptation
    return StepOptions(dgamma=a.dgamma, scaling=a.scaling, step_size=a.step_size, theta=a.theta,
                       damping=a.damping, gamma_limit=a.gamma_limit)


def prepare(config: Config, in_memory: bool = False, **strategies) -> Plan:
    """The :class:`Plan` of ``config`` (with ``strategies`` as in :func:`with_strategies`);
    ``in_memory``: the measurements come from a table given in memory (``auto`` then estimates)."""
    if strategies:
        config = with_strategies(config, **strategies)
    a = config.adaptation
    return Plan(config, ModelSpec.from_config(config.model), derivative_estimator(config.data, in_memory),
                EVALUATORS.resolve(a.evaluation), step_options(config), getattr(torch, a.dtype), torch.device(a.device))


def make_trainer(plan: Plan, diagnostics: bool = False) -> Trainer:
    """The :class:`Trainer` of Algorithm 1 for ``plan`` (``diagnostics``: condition numbers too)."""
    a = plan.config.adaptation
    return Trainer(plan.options, a.round_robin_steps, a.refinement_steps, a.chunk_size, plan.evaluator, diagnostics)
