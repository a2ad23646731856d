"""``diagnose(config, data, validate) -> GapReport``: where the gap lies, which effect causes it,
how far it shrinks.

Flow per state equation: weak-form rows (:mod:`.weak`) -> every hypothesis fitted at once
(:mod:`.hypotheses`, variable projection + damped steps) -> held-out RMSE -> null-verdict rule,
bootstrap trials over time blocks and noise (:mod:`.confidence`) -> catalogue name
(:mod:`.catalogue`) -> localisation (:mod:`.localise`). Then the starting, theta-retuned and
adapted models are compared one-step and in free run (:mod:`msam_torch.simulate`).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch

from ..api import nominal_parameters
from ..candidates import FLOOR, EquationData, columns
from ..config import Config, load_config
from ..data import Dataset, load_datasets, measured_dataset, read_frame
from ..errors import ConfigError, DataError
from ..result import format_component, format_equation
from ..simulation import EquationModel, simulate_equations as simulate
from ..spec import Equation, ModelSpec, split_derivative
from ..step import StepOptions, solve_theta
from . import catalogue, confidence, localise, measures
from .hypotheses import Fitted, Hypothesis, encode, enumerate_hypotheses, extended_equation, fit, predict_rows
from .report import EquationGap, GapReport
from .weak import TestFunctions

EXPLAINED, NO_GAP, NOT_EXPLAINED = "gap explained by {}", "no significant gap", "gap not explained by the candidate set"


@dataclass(frozen=True)
class DiagnoseOptions:
    """Options of :func:`diagnose` (defaults are the documented method)."""

    half_width: float | None = None  # test-function half-width in time units (default: 2 % of the record)
    steps: int = 30  # damped variable-projection steps per hypothesis
    damping: float = 1e-3  # Levenberg-Marquardt damping of the exponent steps
    bootstrap: int = 16  # bootstrap trials (time blocks and noise), run as one batch
    bootstrap_steps: int = 8  # steps per bootstrap trial, warm-started at the original fit
    bootstrap_hypotheses: int = 5  # the best effect hypotheses (and the re-fitted start) re-fitted per trial
    quadrature_samples: int = 1000  # weak-form quadrature uses every k-th sample to stay near this many
    blocks: int = 10  # time blocks for the bootstrap and, without held-out data, the held-out split
    relative: float = 0.05  # null rule: held-out RMSE at least 5 % below the re-fitted starting model
    absolute: float = 0.002  # ... and by 0.2 % of the held-out target's RMS
    min_win_frequency: float = 0.5  # bootstrap share the named effect must win
    snap_keep: float = 0.9  # a catalogue exponent must keep this share of the free exponent's improvement
    max_structure_left: float = 0.25  # residual structure the effect may leave (share of the gap's)
    free_run: bool = True  # simulate the models (torchdiffeq)
    solver: str = "rk4"  # torchdiffeq method of the free-run simulations
    solver_step: float | None = None  # fixed-step size in time units (default: see simulate.simulate)
    rtol: float = 1e-6  # adaptive solvers only
    atol: float = 1e-9
    seed: int = 0


def diagnose(config: Config | dict | str | Path, data: Dataset | str | Path | None = None,
             validate: Dataset | str | Path | None = None, overrides: list[str] = (),
             options: DiagnoseOptions = DiagnoseOptions(), base_dir: str | Path | None = None) -> GapReport:
    """Diagnose the gap between the starting model of ``config`` and measured data.

    ``data``: the training record (a :class:`~msam_torch.data.Dataset` or a CSV/Parquet file read
    with the config's ``data`` columns); default: the config's own data. ``validate``: held-out
    data (default: the config's validation range or file; without any, alternate time blocks of
    the training record are held out). Paths in the config are relative to ``base_dir``
    (default: the config file's folder).
    """
    if base_dir is None:
        base_dir = Path(config).parent if isinstance(config, (str, Path)) else Path(".")
    if not isinstance(config, Config):
        config = load_config(config, overrides)
    if config.adaptation.evaluation == "simulation":
        from .simulated import diagnose_simulated

        return diagnose_simulated(_with_files(config, data, validate), Path(base_dir), options)
    spec = ModelSpec.from_config(config.model)
    dtype = getattr(torch, config.adaptation.dtype)
    train, held_out = _datasets(config, spec, data, validate, base_dir, dtype)
    device = torch.device(config.adaptation.device)
    train, held_out = (None if d is None else replace(d, signals={k: v.to(device) for k, v in d.signals.items()})
                       for d in (train, held_out))
    started = time.perf_counter()  # the diagnosis itself, data loading excluded
    parameters = nominal_parameters(config, spec)
    generator = torch.Generator().manual_seed(options.seed)
    gaps, models, series = [], [], {}
    for equation in spec.equations:
        gap, model, extra = _diagnose_equation(spec, equation, train, held_out, parameters, options, generator)
        gaps.append(gap), models.append(model)
        series[equation.target] = extra
    gap_measures = _measures(spec, models, train, held_out, series, options)
    explained = [g for g in gaps if g.verdict.startswith("gap explained")]
    if explained:
        verdict = "; ".join(f"{g.verdict} in {g.target}" if len(gaps) > 1 else g.verdict for g in explained)
    elif any(g.significant for g in gaps):
        verdict = NOT_EXPLAINED
    else:
        verdict = NO_GAP
    data_info = {"train": dict(train.info), "held_out": dict(held_out.info) if held_out is not None else "alternate time blocks",
                 "nominal_parameters": parameters}
    return GapReport(verdict=verdict, equations=tuple(gaps), measures=gap_measures, data=data_info,
                     options=asdict(options), config=config.model_dump(mode="json"),
                     seconds=time.perf_counter() - started, series=series)


def _with_files(config: Config, data, validate) -> Config:
    """``config`` reading ``data`` and ``validate`` (files) as its training and validation records."""
    if isinstance(data, Dataset) or isinstance(validate, Dataset):
        raise ConfigError("adaptation.evaluation", "evaluation by simulation reads its records from files: "
                          "give data and validate as CSV/Parquet paths")
    update = {}
    if data is not None:
        update.update(file=str(Path(data).resolve()), system=None, validation=None)
    if validate is not None:
        update.update(validation_file=str(Path(validate).resolve()), validation=None)
    return config.model_copy(update={"data": config.data.model_copy(update=update)}) if update else config


def _datasets(config, spec, data, validate, base_dir, dtype):
    if isinstance(data, Dataset):
        train, held_out = data, None
    elif data is not None:
        data_config = config.data.model_copy(update={"file": str(Path(data).resolve()), "system": None,
                                                     "validation": None, "validation_file": None})
        train, held_out = load_datasets(data_config, spec, ".", dtype=dtype)
    else:
        train, held_out = load_datasets(config.data, spec, base_dir, dtype=dtype)
    if isinstance(validate, Dataset):
        held_out = validate
    elif validate is not None:
        frame, source = read_frame(Path(validate))
        held_out = measured_dataset(frame, config.data, spec, source, dtype)
    return train, held_out


def _target_source(equation: Equation, signals: dict) -> tuple[str, int]:
    """The lowest derivative of the target's base that the data hold, and the order left to integrate."""
    base, order = split_derivative(equation.target)
    for k in range(order + 1):
        name = base + {0: "", 1: "_dot", 2: "_ddot"}[k]
        if name in signals:
            return name, order - k
    raise DataError(f"no signal gives {equation.target!r} or a lower derivative of {base!r}")


@dataclass(frozen=True)
class Projection:
    """Integrate columns against the test functions, rows weighted by ``root`` (T, M) or None."""

    tests: TestFunctions
    root: torch.Tensor | None = None

    def __call__(self, cols: torch.Tensor) -> torch.Tensor:
        out = self.tests.integrate(cols)
        return out if self.root is None else out * self.root.view(self.root.shape[:1] + (1, -1, 1))


def _weak_data(extended: Equation, signals: dict, tests: TestFunctions, scale: torch.Tensor | None = None,
               weights: torch.Tensor | None = None, jitter: torch.Tensor | None = None) -> EquationData:
    """Weak-form data of one equation; ``scale`` reuses the training normalisation of F."""
    data = EquationData.build(extended, signals, "functions" if scale is None else "none")
    if scale is not None:
        data = replace(data, log_f=(data.log_f - scale.log()).clamp_min(torch.log(torch.tensor(FLOOR))),
                       scale=scale.unsqueeze(0))
    source, order = _target_source(extended, signals)
    y = (-1) ** order * tests.integrate_signal(signals[source].unsqueeze(0), order)  # (1, M)
    if jitter is not None:
        y = y + jitter
    fixed = tests.integrate(data.fixed_components)
    root = None if weights is None else weights.sqrt()
    if root is not None:
        y, fixed = y * root, fixed * root.unsqueeze(-1)
    return replace(data, y=y, fixed_components=fixed, project=Projection(tests, root))


def _subsample(signals: dict, target: int) -> dict:
    every = max(1, signals["t"].shape[0] // target)
    return {k: v[::every] for k, v in signals.items()}


def _diagnose_equation(spec, equation, train, held_out, parameters, options, generator):
    signals = _subsample(train.signals, options.quadrature_samples)
    t = signals["t"]
    dt = float(t[1] - t[0])
    half_width = options.half_width or 0.02 * float(t[-1] - t[0])
    tests = TestFunctions.build(t, max(4, round(half_width / dt)))
    extended = extended_equation(equation)
    hypotheses = enumerate_hypotheses(equation)
    choices, starts = encode(equation, hypotheses, t.device)
    m = tests.count(t.shape[0])
    pointwise = EquationData.build(extended, signals, "rms")
    scale = pointwise.scale[0]
    if held_out is not None:
        val_signals = _subsample(held_out.signals, options.quadrature_samples)
        val_dt = float(val_signals["t"][1] - val_signals["t"][0])
        val_tests = TestFunctions.build(val_signals["t"], max(4, round(half_width / val_dt)))
        fit_rows = torch.ones(m, dtype=torch.bool, device=t.device)
        val_data = _weak_data(extended, val_signals, val_tests, scale)
        val_rows = torch.ones(val_data.y.shape[-1], dtype=torch.bool, device=t.device)
    else:
        block = torch.div(torch.arange(m, device=t.device) * options.blocks, m, rounding_mode="floor")
        fit_rows = block % 2 == 0
        val_tests, val_signals, val_rows = tests, signals, ~fit_rows
        val_data = _weak_data(extended, signals, tests, scale)
    step_options = StepOptions(scaling="gauss_newton", step_size="one", theta="varpro", damping=options.damping)

    # original fit (one trial), then bootstrap trials warm-started from it
    data = _weak_data(extended, signals, tests, weights=fit_rows.to(t.dtype).unsqueeze(0))
    original = fit(data, choices, starts, step_options, options.steps)
    y_val = val_data.y[0][val_rows]
    target_rms = float(torch.sqrt((y_val**2).mean()))

    def heldout_rmse(fitted, chosen=choices):
        yhat = predict_rows(val_data, chosen, fitted)[..., val_rows]
        rmse = torch.sqrt(((yhat - y_val) ** 2).mean(-1))
        return torch.where(fitted.invalid | ~torch.isfinite(rmse), torch.full_like(rmse, torch.inf), rmse)

    rmse = heldout_rmse(original)[0]  # (C,)
    source, order = _target_source(extended, signals)
    noise = float(train.info.get("noise_level", {}).get(source, 0.0) or 0.0)
    boot_rmse, boot = None, None
    if options.bootstrap > 0:
        weights = confidence.block_weights(fit_rows, options.bootstrap, options.blocks, generator)
        row_noise = noise * float(torch.linalg.vector_norm(tests.kernels[order]))
        jitter = row_noise * torch.randn(options.bootstrap, m, generator=generator, dtype=t.dtype).to(t.device)
        boot_data = _weak_data(extended, signals, tests, weights=weights, jitter=jitter)
        effects = [int(c) for c in torch.argsort(rmse) if c != 0 and torch.isfinite(rmse[c])]
        keep = torch.tensor([0] + effects[:options.bootstrap_hypotheses], device=t.device)
        part = fit(boot_data, choices[keep], original.gamma[:, keep], step_options, options.bootstrap_steps)
        boot = _scatter(part, keep, len(hypotheses))
        boot_rmse = torch.full((options.bootstrap, len(hypotheses)), torch.inf, dtype=t.dtype, device=t.device)
        boot_rmse[:, keep] = heldout_rmse(part, choices[keep])

    nominal = spec.theta(equation, parameters).to(t)
    snap = lambda fit_data, fitted, r: _snapped_names(equation, hypotheses, fit_data, val_data, val_rows, choices,
                                                      fitted, r, nominal, options.snap_keep)
    names, snapped = snap(data, original, rmse.unsqueeze(0))
    names, snapped = names[0], snapped[0]
    is_effect = torch.tensor([h.kind != "retuned" for h in hypotheses], device=t.device)
    candidates_rmse = torch.where(is_effect, rmse, torch.full_like(rmse, torch.inf))
    best = int(candidates_rmse.argmin())
    is_significant = bool(confidence.significant(rmse[best], rmse[0], target_rms, options.relative, options.absolute))
    outcome = names[best] if is_significant else NO_GAP

    # confidence: bootstrap outcomes and the margin to the best hypothesis with another name
    outcomes = []
    if boot_rmse is not None:
        boot_names, _ = snap(boot_data, boot, boot_rmse)
        boot_candidates = torch.where(is_effect, boot_rmse, torch.full_like(boot_rmse, torch.inf))
        for k in range(boot_rmse.shape[0]):
            b = int(boot_candidates[k].argmin())
            ok = bool(confidence.significant(boot_rmse[k, b], boot_rmse[k, 0], target_rms, options.relative, options.absolute))
            outcomes.append(boot_names[k][b] if ok else NO_GAP)
    frequency = confidence.win_frequency(outcomes, outcome) if outcomes else float("nan")
    order_c = [int(c) for c in torch.argsort(rmse) if torch.isfinite(rmse[c])]
    runner = next((c for c in order_c if names[c] != names[best] and c != 0), None) if is_significant else best
    reference = rmse[best] if is_significant else rmse[0]
    margin = float((rmse[runner] - reference) / reference) if runner is not None and reference > 0 else float("inf")

    # structure the best hypothesis leaves, as a share of the structure in the re-fitted start's residual
    structure = _structure_left(equation, signals, tests, val_signals, val_tests, fit_rows, val_rows,
                                data, val_data, choices, original, best)
    if not is_significant:
        verdict = NO_GAP
    elif (outcome != catalogue.NOT_CATALOGUED and not frequency < options.min_win_frequency
          and structure <= options.max_structure_left):
        verdict = EXPLAINED.format(outcome)
    else:
        verdict = NOT_EXPLAINED
    winner = best if is_significant else 0

    # where: robust residual of the starting structure on the training rows
    where = _where(equation, signals)
    components = []
    for i in equation.adjustable:
        touching = [c for c, h in enumerate(hypotheses) if h.component == i]
        c = min(touching, key=lambda c: float(rmse[c]))
        components.append({"component": equation.components[i].term.text, "best_hypothesis": hypotheses[c].label(equation),
                           "heldout_rmse": float(rmse[c]), "improvement": float(1 - rmse[c] / rmse[0])})
    components.sort(key=lambda d: -d["improvement"])
    ranking = [{"hypothesis": hypotheses[c].label(equation), "kind": hypotheses[c].kind, "effect": names[c],
                "exponent": _exponent(hypotheses[c], equation, original.gamma[0, c]),
                "catalogue_exponent": _named_exponent(hypotheses[c], equation, names[c], snapped[c]),
                "equation": _equation_text(extended, equation, choices[c], original.gamma[0, c],
                                           _data_theta(original, c, choices, scale), original.theta_fixed[0, c]),
                "heldout_rmse": float(rmse[c]), "improvement": float(1 - rmse[c] / rmse[0])} for c in order_c]
    model = _models(extended, equation, nominal, choices, original, boot, boot_rmse, winner, is_effect, scale)
    gap = EquationGap(
        target=equation.target, significant=is_significant, verdict=verdict,
        effect=outcome if is_significant else None,
        hypothesis=hypotheses[winner].label(equation),
        exponent=_exponent(hypotheses[winner], equation, original.gamma[0, winner]),
        catalogue_exponent=_named_exponent(hypotheses[winner], equation, names[winner], snapped[winner]),
        start_equation=format_equation(equation.target, nominal.tolist(),
                                       [format_component(equation, i, None, None) for i in range(len(equation.components))]),
        retuned_equation=_equation_text(extended, equation, choices[0], original.gamma[0, 0],
                                        _data_theta(original, 0, choices, scale), original.theta_fixed[0, 0]),
        adapted_equation=_equation_text(extended, equation, choices[winner], original.gamma[0, winner],
                                        _data_theta(original, winner, choices, scale), original.theta_fixed[0, winner]),
        confidence={"margin": margin, "runner_up": names[runner] if runner is not None and is_significant else None,
                    "win_frequency": frequency, "bootstrap_trials": len(outcomes),
                    "outcomes": {o: outcomes.count(o) for o in sorted(set(outcomes))}},
        improvement={"retuned_rmse": float(rmse[0]), "adapted_rmse": float(rmse[winner]),
                     "relative": float(1 - rmse[winner] / rmse[0]), "target_rms": target_rms,
                     "rule": {"relative": options.relative, "absolute": options.absolute}},
        structure_left=structure, components=components, ranking=ranking, where=where["summary"],
        estimator={"test_function": "bump (1-s^2)^4", "half_width": tests.half_width * dt,
                   "half_width_samples": tests.half_width, "rows": m, "derivatives": train.info.get("derivatives")},
    )
    return gap, model, {"where": where["series"]}


def _scatter(part: Fitted, keep: torch.Tensor, c: int) -> Fitted:
    """Bootstrap results of the hypotheses ``keep`` placed among all ``c`` (others invalid)."""
    def full(x, fill):
        out = torch.full((x.shape[0], c) + x.shape[2:], fill, dtype=x.dtype, device=x.device)
        out[:, keep] = x
        return out
    return Fitted(full(part.gamma, 0.0), full(part.theta, 0.0), full(part.theta_fixed, 0.0),
                  full(part.fitness, -torch.inf), full(part.invalid, True))


def _slot(equation: Equation, h: Hypothesis) -> int:
    q = len(equation.adjustable)
    return equation.adjustable.index(h.component) + (q if h.kind == "additive" else 0)


def _named_exponent(h: Hypothesis, equation: Equation, name: str, gamma: torch.Tensor) -> float | None:
    """The exponent a catalogue name refers to (the fitted one moved into the entry's interval)."""
    if h.kind == "retuned" or name in (NO_GAP, catalogue.NOT_CATALOGUED):
        return None
    return float(gamma[_slot(equation, h)])


def _snapped_names(equation, hypotheses, fit_data, val_data, val_rows, choices, fitted, rmse, nominal, keep):
    """Catalogue names of every trial and hypothesis (T, C) and the exponents they name.

    Each effect exponent is moved to the nearest catalogued value for its signal roles, theta is
    re-solved (variable projection), and the name is given when the snapped model keeps ``keep``
    of the free exponent's held-out improvement over the re-fitted start; else 'power law, no
    catalogued effect'."""
    gamma = fitted.gamma.clone()
    for c, h in enumerate(hypotheses):
        entries = [] if h.kind == "retuned" else catalogue.entries_for(equation, h.component, h.function)
        if entries:
            g = gamma[:, c, _slot(equation, h)]
            options = torch.stack([g.clamp(e.low, e.high) for e in entries], -1)
            nearest = (options - g.unsqueeze(-1)).abs().argmin(-1, keepdim=True)
            gamma[:, c, _slot(equation, h)] = options.gather(-1, nearest).squeeze(-1)
    selection = fit_data.select(choices)
    theta, theta_fixed = solve_theta(selection, columns(selection, gamma))
    moved = Fitted(gamma, theta, theta_fixed, fitted.fitness, fitted.invalid)
    yhat = predict_rows(val_data, choices, moved)[..., val_rows]
    y = val_data.y[0][val_rows]
    snapped_rmse = torch.sqrt(((yhat - y) ** 2).mean(-1))
    kept = (rmse[:, :1] - snapped_rmse) >= keep * (rmse[:, :1] - rmse)
    names = []
    for k in range(gamma.shape[0]):
        row = []
        for c, h in enumerate(hypotheses):
            if h.kind == "retuned":
                row.append(NO_GAP)
                continue
            s = _slot(equation, h)
            named = catalogue.name_effect(equation, h.component, h.function, float(gamma[k, c, s]),
                                          float(theta[k, c, s]), float(nominal[h.component]))
            row.append(named if bool(kept[k, c]) else catalogue.NOT_CATALOGUED)
        names.append(row)
    return names, gamma


def _exponent(h: Hypothesis, equation: Equation, gamma: torch.Tensor) -> float | None:
    if h.kind == "retuned":
        return None
    q = len(equation.adjustable)
    return float(gamma[equation.adjustable.index(h.component) + (q if h.kind == "additive" else 0)])


def _data_theta(fitted, c, choices, scale, trial=0) -> torch.Tensor:
    """Theta in the data's units: the normalisation ``|f/s|^gamma`` folded back (``s^-gamma``)."""
    return fitted.theta[trial, c] * scale[choices[c]] ** (-fitted.gamma[trial, c])


def _equation_text(extended, equation, choice, gamma, theta, theta_fixed) -> str:
    """The hypothesis as an equation in the paper's notation (switched-off copies left out)."""
    n_f = len(equation.adjustments)
    slot = {i: k for k, i in enumerate(extended.adjustable)}
    fixed = {i: k for k, i in enumerate(extended.fixed)}
    thetas, terms = [], []
    for i in range(len(extended.components)):
        if i in fixed:
            thetas.append(float(theta_fixed[fixed[i]]))
            terms.append(format_component(extended, i, None, None))
            continue
        k = slot[i]
        f = int(choice[k])
        if f == n_f + 1:
            continue
        thetas.append(float(theta[k]))
        terms.append(format_component(extended, i, None if f == n_f else f, float(gamma[k])))
    return format_equation(equation.target, thetas, terms)


def _models(extended, equation, nominal, choices, original, boot, boot_rmse, winner, is_effect, scale):
    """Extended-form models batched as [start, retuned, adapted, (retuned, adapted) per bootstrap trial]."""
    q = len(equation.adjustable)
    start_theta = torch.cat([nominal[list(equation.adjustable)], nominal.new_zeros(q)])
    rows = [(choices[0], torch.zeros_like(original.gamma[0, 0]), start_theta, nominal[list(equation.fixed)])]
    for c in (0, winner):
        rows.append((choices[c], original.gamma[0, c], original.theta[0, c], original.theta_fixed[0, c]))
    if boot is not None:
        for k in range(boot.gamma.shape[0]):
            cands = torch.where(is_effect, boot_rmse[k], torch.full_like(boot_rmse[k], torch.inf))
            b = winner if winner == 0 else int(cands.argmin())
            for c in (0, b):
                rows.append((choices[c], boot.gamma[k, c], boot.theta[k, c], boot.theta_fixed[k, c]))
    stack = lambda j: torch.stack([r[j] for r in rows])
    return EquationModel(extended, stack(0), stack(1), stack(2), stack(3), scale)


def _features(equation, signals, tests):
    names = sorted(n for n in equation.signals - {equation.target, "t"} if n in signals)
    return names, torch.stack([tests.average(signals[n]) for n in names], -1)


def _structure_left(equation, signals, tests, val_signals, val_tests, fit_rows, val_rows, data, val_data,
                    choices, original, best) -> float:
    """Share of the re-fitted start's residual structure (what a k-nearest-neighbour regression on
    the equation's signals predicts on held-out rows) that hypothesis ``best`` leaves."""
    names, x_fit = _features(equation, signals, tests)
    _, x_val = _features(equation, val_signals, val_tests)
    x_fit, x_val = x_fit[fit_rows], x_val[val_rows]
    spread = x_fit.std(0).clamp_min(torch.finfo(x_fit.dtype).tiny)
    distance = torch.cdist(x_val / spread, x_fit / spread)
    k = min(10, x_fit.shape[0])
    neighbours = distance.topk(k, largest=False).indices
    fit_pred = predict_rows(data, choices, original)[0]  # rows of the weighted fit: weights are 0/1
    val_pred = predict_rows(val_data, choices, original)[0]
    explained = []
    for c in (0, best):
        r_fit = (data.y[0] - fit_pred[c])[fit_rows]
        r_val = (val_data.y[0] - val_pred[c])[val_rows]
        guess = r_fit[neighbours].mean(-1)
        explained.append(float(((r_val**2).mean() - ((r_val - guess) ** 2).mean()).clamp_min(0)))
    return explained[1] / explained[0] if explained[0] > 0 else 0.0


def _where(equation, signals) -> dict:
    """Two-regime search on the one-step (pointwise) rows of the training record (:mod:`.localise`);
    pointwise, because a weak-form row mixes the states over its test function's window."""
    data = EquationData.build(equation, signals, "none")
    design = torch.cat([data.components[0], data.fixed_components[0]], -1)
    return localise.where(signals["t"], design, data.y[0], signal_values(equation, signals))


def signal_values(equation: Equation, signals: dict) -> dict:
    """The signals an equation reads (its target and time left out), by name."""
    return {n: signals[n] for n in sorted(equation.signals - {equation.target, "t"}) if n in signals}


def _measures(spec, models, train, held_out, series, options) -> dict:
    """One-step and free-run measures of the three models on training and held-out data.

    Held-out data are simulated with every bootstrap trial's models (for the interval of the gap
    closed); training data with the three point models (all, when there are no held-out data)."""
    out = {"one_step": {}, "free_run": {}}
    sets = {"train": train, "held_out": held_out} if held_out is not None else {"train": train}
    for label, dataset in sets.items():
        s = dataset.signals
        one_step = {}
        for model in models:
            yhat = model.rate({k: v.unsqueeze(0) for k, v in s.items()})[:3]  # (3, N)
            one_step[model.equation.target] = measures.by_model(measures.error_measures(s[model.equation.target], yhat))
            series[model.equation.target][f"one_step_{label}"] = {"t": s["t"], "y": s[model.equation.target], "yhat": yhat}
        out["one_step"][label] = one_step
    if not options.free_run:
        return out
    batches = {label: models if label == list(sets)[-1] else [_first(m, 3) for m in models] for label in sets}
    trajectories = _simulate_sets(spec, sets, batches, options)
    for label, dataset in sets.items():
        s, trajectory = dataset.signals, trajectories[label]
        measured = [x for x in spec.states if x in dataset.info.get("measured", spec.states)] or list(spec.states)
        per_state = {x: measures.by_model(measures.error_measures(s[x], trajectory[x][:3])) for x in spec.states}
        nrmse_all = torch.stack([torch.tensor(measures.error_measures(s[x], trajectory[x])["nrmse"])
                                 for x in measured]).mean(0)
        entry = {"states": per_state, "measured_states": measured,
                 "nrmse": dict(zip(measures.MODELS, nrmse_all[:3].tolist()))}
        entry["gap_closed"] = {k: float(v[0]) for k, v in measures.closure(nrmse_all[0:1], nrmse_all[1:2], nrmse_all[2:3]).items()}
        if nrmse_all.shape[0] > 3:
            boot = measures.closure(nrmse_all[0].expand(nrmse_all[3::2].shape), nrmse_all[3::2], nrmse_all[4::2])
            entry["gap_closed_interval"] = {k: measures.interval(v) for k, v in boot.items()}
        out["free_run"][label] = entry
        for target in series:
            series[target][f"free_run_{label}"] = {"t": s["t"], "measured": {x: s[x] for x in measured},
                                                   "simulated": {x: trajectory[x][:3] for x in measured}}
    return out


def _simulate_sets(spec, sets: dict, batches: dict, options) -> dict:
    """Free runs from each set's first (estimated) state under its inputs; sets on the same time
    grid are integrated in one batch."""
    grids = {label: d.signals["t"] for label, d in sets.items()}
    same = len(sets) == 2 and grids["train"].shape == grids["held_out"].shape and torch.allclose(
        grids["train"], grids["held_out"])
    groups = [list(sets)] if same else [[label] for label in sets]
    result = {}
    for group in groups:
        sizes = [batches[label][0].choice.shape[0] for label in group]
        models = [_concat([batches[label][e] for label in group]) for e in range(len(batches[group[0]]))]
        inputs = {u: torch.cat([sets[label].signals[u].expand(n, -1) for label, n in zip(group, sizes)])
                  for u in spec.inputs}
        initial = {x: torch.cat([sets[label].signals[x][0].expand(n) for label, n in zip(group, sizes)]) for x in spec.states}
        scale = {x: max(float(sets[label].signals[x].abs().max()) for label in group) for x in spec.states}
        trajectory = simulate(spec, models, grids[group[0]], inputs, initial, method=options.solver,
                              step=options.solver_step, rtol=options.rtol, atol=options.atol, scale=scale)
        offsets = [0] + torch.tensor(sizes).cumsum(0).tolist()
        for k, label in enumerate(group):
            result[label] = {x: v[offsets[k]:offsets[k + 1]] for x, v in trajectory.items()}
    return result


def _concat(models: list[EquationModel]) -> EquationModel:
    if len(models) == 1:
        return models[0]
    cat = lambda name: torch.cat([getattr(m, name) for m in models])
    return EquationModel(models[0].equation, cat("choice"), cat("gamma"), cat("theta"), cat("theta_fixed"), models[0].scale)


def _first(model: EquationModel, b: int) -> EquationModel:
    return EquationModel(model.equation, model.choice[:b], model.gamma[:b], model.theta[:b], model.theta_fixed[:b],
                         model.scale)
