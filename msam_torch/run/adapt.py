"""The Python entry point: ``adapt(config)`` runs MSAM on every state equation of a config."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch

from msam_torch.config.schema import Config, load_config
from msam_torch.data.loading import DataArgument, Dataset, resolve_datasets
from msam_torch.data.systems import perturb_parameters
from msam_torch.engine.candidates import EquationData, equation_choices
from msam_torch.engine.trainer import Fit, Trainer
from msam_torch.engine.tuning import Tuned, measure_model, relative_error, tune_adapted, tune_start
from msam_torch.engine.weak_form import TestFunctions, resolves, weak_data
from msam_torch.model.notation import format_component, format_equation
from msam_torch.model.spec import Equation, ModelSpec
from msam_torch.run.adapt_simulated import adapt_simulation
from msam_torch.run.estimation import Estimation, choose, regressor_band
from msam_torch.run.plan import Plan, make_trainer, prepare, records_measured
from msam_torch.run.progress import LOGGER
from msam_torch.run.result import EquationResult, RunResult


def nominal_parameters(config: Config, spec: ModelSpec) -> dict:
    """The model's parameters with the configured parametric error drawn from ``data.seed``."""
    generator = torch.Generator().manual_seed(config.data.seed)
    return perturb_parameters(spec.parameters, config.data.parametric_error, generator)


def adapt(config: Config | dict | str, overrides: list[str] = (),
          on_trainer: Callable[[Trainer, Equation], None] | None = None, base_dir: str | Path | None = None,
          data: DataArgument = None, validation: DataArgument = None,
          trainer_factory: Callable[[Plan], Trainer] | None = None, **strategies) -> RunResult:
    """Run Algorithm 1 on each state equation; ``on_trainer`` may attach callbacks.

    Data file paths are relative to ``base_dir`` (default: the config file's folder). ``data``
    (and ``validation``) replace the config's record (held-out record): a CSV/Parquet path, a
    pandas DataFrame or a mapping of column name to 1-D array or tensor, read through the
    config's ``data`` section, or a :class:`~msam_torch.data.loading.Dataset` (see
    :func:`~msam_torch.data.loading.resolve_datasets`).
    ``trainer_factory`` builds the trainer from the :class:`~msam_torch.run.plan.Plan` (default
    :func:`~msam_torch.run.plan.make_trainer`; see :mod:`msam_torch.run.distributed` for the round robin
    sharded over processes). ``strategies``: ``derivatives``, ``evaluation``, ``step_size`` or
    ``theta`` as objects (or names) in place of the config's, e.g.
    ``adapt(config, data=frame, derivatives=SavitzkyGolay(window=15))``."""
    if base_dir is None:
        base_dir = Path(config).parent if isinstance(config, (str, Path)) else Path(".")
    if not isinstance(config, Config):
        config = load_config(config, overrides)
    plan = prepare(config, in_memory=data is not None, measured=records_measured(config, data), **strategies)
    config, spec, dtype, device = plan.config, plan.spec, plan.dtype, plan.device
    if plan.simulates:
        return adapt_simulation(plan, nominal_parameters(config, spec), Path(base_dir), trainer_factory or make_trainer,
                                on_trainer, data, validation)
    train, held_out = resolve_datasets(config.data, spec, base_dir, dtype, data, validation, plan.derivatives)
    signals = {k: v.to(device) for k, v in train.signals.items()}
    provenance = train.info if held_out is None else {**train.info, "validation": held_out.info}
    parameters = nominal_parameters(config, spec)
    results = []
    held_signals = None if held_out is None else {k: v.to(device) for k, v in held_out.signals.items()}
    tests, estimation = None, weak_estimation(plan, train)
    if estimation is not None:  # the regressors' band sets the test functions and the smoothing
        signals = {k: v.to(device) for k, v in estimation.train.items()}
        tests = TestFunctions.spanning(signals["t"], estimation.half_width)
        provenance = {**provenance, "weak_form": {"half_width": estimation.half_width, **estimation.info}}
    provenance = {**provenance, "form": "strong" if tests is None else "weak"}
    for equation in spec.equations:
        theta = spec.theta(equation, parameters).to(device=device, dtype=dtype)
        trainer = (trainer_factory or make_trainer)(plan)
        if on_trainer is not None:
            on_trainer(trainer, equation)
        results += adapt_equation(config, equation, signals, theta, trainer, held_signals, tests)
    provenance = {**provenance, "nominal_parameters": parameters}
    return RunResult(results, config.model_dump(mode="json"), provenance)


def weak_estimation(plan: Plan, train: Dataset) -> Estimation | None:
    """The weak form's signals and test functions for ``adaptation.form`` (None: Eq. 6 on estimated
    derivatives); ``auto`` takes the weak form where test functions of a few samples
    (:func:`~msam_torch.engine.weak_form.resolves`) pass the band of the signals the regressors read."""
    form = plan.config.adaptation.form
    if form == "strong":
        return None
    band = regressor_band(plan.spec, train)
    if form == "auto" and not resolves(band[0]):  # decided before the record is re-estimated for the weak form
        LOGGER.info("Eq. 6 on estimated derivatives: the regressors' band, %.4g cycles per sample, is too close to "
                    "the sampling rate for test functions of a few samples", band[0])
        return None
    return choose(plan.spec, plan.config.data, train, None, plan.derivatives, band=band)


def adapt_equation(config: Config, equation: Equation, signals: dict, theta: torch.Tensor,
                   trainer: Trainer | None = None, held_out: dict | None = None,
                   tests: TestFunctions | None = None) -> list[EquationResult]:
    """Algorithm 1 on one state equation for a batch of T trials at once.

    ``signals``: name -> (N,) or (T, N); ``theta``: nominal theta of every component, (K,) or
    (T, K). Theta is re-estimated for the starting model (used as the start when
    ``adaptation.tune_theta``) and for the adapted model; ``held_out`` signals (N,) are scored too
    (one step ahead, Eq. 6). With ``tests`` the rows are Eq. 6 in weak form (:mod:`msam_torch.engine.weak_form`)
    on the weak form's ``signals`` (:func:`~msam_torch.run.estimation.choose`).
    Returns one :class:`EquationResult` per trial."""
    a = config.adaptation
    theta = theta if theta.dim() == 2 else theta.unsqueeze(0)
    trials = max([theta.shape[0]] + [v.shape[0] for v in signals.values() if v.dim() == 2])
    signals = {k: v.expand(trials, v.shape[-1]) for k, v in signals.items()}
    theta = theta.expand(trials, -1)
    data = (EquationData.build(equation, signals, a.normalize) if tests is None
            else weak_data(equation, signals, tests, normalize=a.normalize))
    theta_adjustable = theta[:, list(equation.adjustable)] * data.theta_scale
    theta_fixed = theta[:, list(equation.fixed)]
    tuned_start = tune_start(data, theta_fixed, a.hold_fixed)
    if a.tune_theta:
        theta_adjustable, theta_fixed = tuned_start.theta, tuned_start.theta_fixed
    trainer = make_trainer(prepare(config)) if trainer is None else trainer
    start = torch.tensor([equation.components[i].start for i in equation.adjustable], dtype=data.y.dtype,
                         device=data.y.device)
    fit = trainer.fit(data, theta_adjustable, theta_fixed, start, choices=equation_choices(equation, data.y.device))
    tuned_adapted = tune_adapted(data, fit.choices[fit.winner], fit.gamma, fit.theta_fixed, a.hold_fixed)
    held = None if held_out is None else EquationData.build(equation, held_out)
    tuning = Tuning(tuned_start, tuned_adapted, a.tune_theta, a.hold_fixed, held)
    return [equation_result(equation, fit, theta[i], data.scale[i], i, tuning, data.theta_scale[i])
            for i in range(trials)]


@dataclass(frozen=True)
class Tuning:
    """Theta re-estimated for the starting model (``retuned``) and the adapted one
    (``adapted_retuned``), and the held-out data."""

    retuned: Tuned
    adapted_retuned: Tuned
    used_for_start: bool
    hold_fixed: bool
    validation: EquationData | None = None


def candidate_label(equation: Equation, choice) -> list[str]:
    return [equation.adjustments[int(f)].text for f in choice]


def in_order(equation: Equation, adjustable, fixed) -> list[float]:
    """Per-component values in the equation's order from the adjustable and fixed parts."""
    slot = {i: k for k, i in enumerate(equation.adjustable)}
    fixed_slot = {i: k for k, i in enumerate(equation.fixed)}
    return [float(adjustable[slot[i]]) if i in slot else float(fixed[fixed_slot[i]])
            for i in range(len(equation.components))]


def equation_result(equation: Equation, fit: Fit, theta: torch.Tensor, scale: torch.Tensor, trial: int = 0,
                    tuning: Tuning | None = None, component_scale: torch.Tensor | None = None) -> EquationResult:
    """One trial of a :class:`Fit` as an :class:`EquationResult`; ``theta`` is the trial's nominal
    theta of every component (the starting equation shows the tuned one if it was the start).

    With normalised adjustment functions (``f / s``) and components (``M / c``) the printed theta
    absorbs ``s^-gamma / c`` so the equation reads in the data's own units.
    """
    winner = int(fit.winner[trial])
    choice = fit.choices[winner].tolist()
    gamma = fit.gamma[trial].tolist()
    to_data_units = scale[fit.choices[winner]] ** (-fit.gamma[trial])
    if component_scale is not None:
        to_data_units = to_data_units / component_scale
    thetas = in_order(equation, fit.theta[trial] * to_data_units, fit.theta_fixed[trial])
    slot = {i: k for k, i in enumerate(equation.adjustable)}
    terms = [format_component(equation, i, choice[slot[i]], gamma[slot[i]]) if i in slot
             else format_component(equation, i, None, None) for i in range(len(equation.components))]
    adjustments = [equation.adjustments[choice[slot[i]]].text if i in slot else None
                   for i in range(len(equation.components))]
    exponents = [gamma[slot[i]] if i in slot else None for i in range(len(equation.components))]
    order = torch.argsort(fit.ranking_fitness[trial], descending=True).tolist()
    ranking = [{"candidate": c, "adjustments": candidate_label(equation, fit.choices[c]),
                "fitness": float(fit.ranking_fitness[trial, c]),
                "exponents": fit.ranking_gamma[trial, c].tolist(),
                "diverged": bool(fit.diverged[trial, c])} for c in order]
    pick = lambda d: {k: float(v[trial]) for k, v in d.items()}
    start_terms = [format_component(equation, i, None, None) for i in range(len(equation.components))]
    start_theta = theta.tolist()
    extra = {}
    if tuning is not None:
        nominal = theta.to(fit.gamma.dtype)
        start_units = 1.0 if component_scale is None else 1.0 / component_scale
        tuned_theta = in_order(equation, tuning.retuned.theta[trial] * start_units, tuning.retuned.theta_fixed[trial])
        if tuning.used_for_start:
            start_theta = tuned_theta
        adapted_theta = in_order(equation, tuning.adapted_retuned.theta[trial] * to_data_units,
                                 tuning.adapted_retuned.theta_fixed[trial])
        error = lambda tuned: relative_error(nominal.cpu(), torch.tensor(tuned, dtype=nominal.dtype)).tolist()
        extra["theta_tuning"] = {
            "used_for_start": tuning.used_for_start, "hold_fixed": tuning.hold_fixed,
            "retuned": {"equation": format_equation(equation.target, tuned_theta, start_terms), "theta": tuned_theta,
                        **pick(tuning.retuned.measures), "nominal_error": error(tuned_theta)},
            "adapted_retuned": {"equation": format_equation(equation.target, adapted_theta, terms), "theta": adapted_theta,
                                **pick(tuning.adapted_retuned.measures), "nominal_error": error(adapted_theta)},
        }
        if tuning.validation is not None:
            extra["validation"] = validation_measures(equation, fit, tuning, nominal, to_data_units, start_units, trial)
    return EquationResult(
        target=equation.target,
        equation=format_equation(equation.target, thetas, terms),
        start_equation=format_equation(equation.target, start_theta, start_terms),
        adjustments=adjustments, exponents=exponents, theta=thetas,
        start=pick(fit.start), adapted=pick(fit.adapted), ranking=ranking,
        diverged=int(fit.diverged[trial].sum()), **extra,
    )


def validation_measures(equation: Equation, fit: Fit, tuning: Tuning, nominal: torch.Tensor,
                        to_data_units: torch.Tensor, start_units, trial: int) -> dict:
    """Measures on the held-out data of the ``start``, ``retuned``, ``adapted`` and ``adapted_retuned``
    models (one-step, algebraic; the held-out data are not normalised: theta is in data units)."""
    held = tuning.validation
    choice = fit.choices[fit.winner[trial]].unsqueeze(0)
    gamma = fit.gamma[trial].unsqueeze(0)
    adjustable, fixed = list(equation.adjustable), list(equation.fixed)
    models = {
        "start": (None, nominal[adjustable], nominal[fixed]),
        "retuned": (None, tuning.retuned.theta[trial] * start_units, tuning.retuned.theta_fixed[trial]),
        "adapted": (choice, fit.theta[trial] * to_data_units, fit.theta_fixed[trial]),
        "adapted_retuned": (choice, tuning.adapted_retuned.theta[trial] * to_data_units,
                            tuning.adapted_retuned.theta_fixed[trial]),
    }
    return {name: {k: float(v[0]) for k, v in measure_model(held, c, gamma, th.unsqueeze(0), tf.unsqueeze(0)).items()}
            for name, (c, th, tf) in models.items()}
