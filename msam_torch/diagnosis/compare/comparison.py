"""Comparison of models: the starting, theta-retuned and adapted models (and every bootstrap
trial's retuned and adapted pair) one-step and in free run (:mod:`msam_torch.simulation`) on the
training and held-out data, with the part of the gap each closes (:mod:`.measures`)."""
from __future__ import annotations

import math

import torch

from msam_torch.data.filters import butterworth, zero_phase
from msam_torch.diagnosis.compare import measures
from msam_torch.diagnosis.compare.confidence import best_effect
from msam_torch.diagnosis.effects.bootstrap import Bootstrap
from msam_torch.diagnosis.effects.hypotheses import Fitted
from msam_torch.diagnosis.options import AGREEMENT, DiagnoseOptions
from msam_torch.errors import MSAMError
from msam_torch.model.spec import Equation, ModelSpec
from msam_torch.simulation.equations import EquationModel, fastest_decay
from msam_torch.simulation.equations import simulate_equations as simulate
from msam_torch.simulation.solver import STABILITY, TABLEAUS

PER_PERIOD = 0.04  # a fixed step starts at most at this share of the band's period
STEPS = 500  # ... and at most at this share of the record
CHECK_STEPS = 1000  # the step is checked over this many of its steps from the record's start
HALVINGS = 2  # a fixed step is halved at most this often (then the runs are marked not converged)
STABLE_SHARE = 0.9  # twice a fixed step's start is at most this share of the step the fastest decaying mode allows
STIFF_SUBSTEPS = 16  # ... and at least at this share of the sample period (then the model is too stiff for it)
MODES_AT = 64  # record samples the modes are computed at
DIVERGED = 10.0  # a free run this many standard deviations off the measurement (NRMSE) has diverged


def models(extended: Equation, equation: Equation, nominal: torch.Tensor, choices: torch.Tensor, original: Fitted,
           boot: Bootstrap | None, winner: int, is_effect: torch.Tensor, scale: torch.Tensor) -> EquationModel:
    """Extended-form models batched as [start, retuned, adapted, (retuned, adapted) per bootstrap trial]."""
    q = len(equation.adjustable)
    start_theta = torch.cat([nominal[list(equation.adjustable)], nominal.new_zeros(choices.shape[-1] - q)])
    rows = [(choices[0], torch.zeros_like(original.gamma[0, 0]), start_theta, nominal[list(equation.fixed)])]
    for c in (0, winner):
        rows.append((choices[c], original.gamma[0, c], original.theta[0, c], original.theta_fixed[0, c]))
    if boot is not None:
        fitted = boot.fitted
        for k, best in enumerate(best_effect(boot.rmse, is_effect).tolist()):
            b = winner if winner == 0 else best
            for c in (0, b):
                rows.append((choices[c], fitted.gamma[k, c], fitted.theta[k, c], fitted.theta_fixed[k, c]))
    stack = lambda j: torch.stack([r[j] for r in rows])
    return EquationModel(extended, stack(0), stack(1), stack(2), stack(3), scale)


def check_solver(method: str) -> None:
    """A torchdiffeq method name, else an error naming the option."""
    if method in TABLEAUS:  # the fixed-step methods, without importing torchdiffeq (and with it scipy)
        return
    from torchdiffeq._impl.odeint import SOLVERS  # the method names odeint accepts (no public list)

    if method not in SOLVERS:
        raise MSAMError(f"solver: {method!r} is not a torchdiffeq method (one of {', '.join(sorted(SOLVERS))})")


def compare(spec: ModelSpec, models: list[EquationModel], train, held_out, series: dict, options: DiagnoseOptions,
            band: float = math.inf, starts: dict | None = None, held: dict | None = None) -> dict:
    """One-step and free-run measures of the three models on training and held-out data; the
    arrays the plots draw are added to ``series`` (per target); ``band``: the band edge of the
    measured states (cycles per time unit), which bounds a fixed solver step. The free runs are
    scored against the states as recorded (not as the data loader smoothed them) and start from
    ``starts[label]``'s first samples where given (the diagnosis's own view of each record: its
    weak-form signals), else from the dataset's, under the inputs as recorded (``held[label]``: the
    inputs that record holds between samples, as the weak form reads them; the others interpolated
    linearly). A free run that diverges (not finite, or NRMSE
    above :data:`DIVERGED`) is listed in ``diverged`` and has no NRMSE.

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
            series[model.equation.target][f"one_step_{label}"] = {"t": s["t"], "y": s[model.equation.target], "yhat": yhat,
                                                                  "inputs": {u: s[u] for u in spec.inputs if u in s}}
        out["one_step"][label] = one_step
    if not options.free_run:
        return out
    batches = {label: models if label == list(sets)[-1] else [_first(m, 3) for m in models] for label in sets}
    trajectories, solvers = _simulate_sets(spec, sets, batches, options, band, starts or {}, held or {})
    for label, dataset in sets.items():
        s, trajectory = recorded(dataset), trajectories[label]
        measured = [x for x in spec.states if x in dataset.info.get("measured", spec.states)] or list(spec.states)
        per_state = {x: measures.by_model(measures.error_measures(s[x], trajectory[x][:3])) for x in spec.states}
        nrmse_all = torch.stack([torch.tensor(measures.error_measures(s[x], trajectory[x])["nrmse"])
                                 for x in measured]).mean(0)
        off = ~torch.isfinite(nrmse_all[:3]) | (nrmse_all[:3] > DIVERGED)
        entry = {"states": per_state, "measured_states": measured,
                 "nrmse": {m: None if o else v for m, v, o in zip(measures.MODELS, nrmse_all[:3].tolist(), off.tolist())},
                 "diverged": [m for m, o in zip(measures.MODELS, off.tolist()) if o], "solver": solvers[label]}
        entry["gap_closed"] = {k: float(v[0]) for k, v in measures.closure(nrmse_all[0:1], nrmse_all[1:2], nrmse_all[2:3]).items()}
        if nrmse_all.shape[0] > 3:
            boot = measures.closure(nrmse_all[0].expand(nrmse_all[3::2].shape), nrmse_all[3::2], nrmse_all[4::2])
            entry["gap_closed_interval"] = {k: measures.interval(v) for k, v in boot.items()}
        out["free_run"][label] = entry
        for target in series:
            series[target][f"free_run_{label}"] = {"t": s["t"], "measured": {x: s[x] for x in measured},
                                                   "simulated": {x: trajectory[x][:3] for x in measured},
                                                   "inputs": {u: s[u] for u in spec.inputs}}
    return out


def recorded(dataset) -> dict:
    """A dataset's signals with the measured ones as recorded (unsmoothed)."""
    return {**dataset.signals, **dataset.measured}


def _simulate_sets(spec: ModelSpec, sets: dict, batches: dict, options: DiagnoseOptions, band: float,
                   starts: dict, held: dict) -> tuple:
    """Free runs from each set's first state (``starts[label]``, else the set's) under its inputs;
    sets on the same time grid that hold the same inputs are integrated in one batch. A fixed-step solver without a given step starts at
    :func:`_first_step` (a share of the band's period within the models' stability interval) and halves it
    until the three point models' runs at the step and at twice it agree (:func:`converged`) over
    the first :data:`CHECK_STEPS` steps, at most :data:`HALVINGS` times (each set's ``solver``
    entry says whether they agreed, and ``unconverged`` which did not); a step they agree at at
    once is doubled while they agree at the doubled step (:func:`_doubles`): the step follows the
    dynamics, not the record's length or sampling, so the cost grows linearly with the record. An
    adaptive solver keeps its tolerances, ``atol`` relative to each state's measured magnitude."""
    grids = {label: d.signals["t"] for label, d in sets.items()}
    same = len(sets) == 2 and grids["train"].shape == grids["held_out"].shape and torch.allclose(
        grids["train"], grids["held_out"]) and set(held.get("train", ())) == set(held.get("held_out", ()))
    groups = [list(sets)] if same else [[label] for label in sets]
    fixed = options.solver in TABLEAUS
    result, steps = {}, {}
    for group in groups:
        t = grids[group[0]]
        sizes = [batches[label][0].choice.shape[0] for label in group]
        batch = [_concat([batches[label][e] for label in group]) for e in range(len(batches[group[0]]))]
        step, agree, trajectory = options.solver_step, torch.ones(3 * len(group), dtype=torch.bool), None
        auto, dt = fixed and step is None, float(t[1] - t[0])
        initial = {x: torch.cat([_first_sample(x, starts.get(label), sets[label].signals).expand(n)
                                 for label, n in zip(group, sizes)]) for x in spec.states}
        stiff = False
        if auto:
            step, stiff, widest = _first_step(spec, {label: sets[label] for label in group}, batches, starts, options.solver,
                                      band, t, bool(held.get(group[0])))
        seen = lambda u: anti_aliased(u, dt, 2 * step if auto else step) if fixed else u
        inputs = {u: torch.cat([seen(sets[label].signals[u]).expand(n, -1) for label, n in zip(group, sizes)])
                  for u in spec.inputs}
        views = {label: recorded(sets[label]) for label in group}
        scale = {x: max(float(views[label][x].abs().max()) for label in group) for x in spec.states}
        atol = torch.tensor([options.atol * max(scale[x], torch.finfo(t.dtype).tiny) for x in spec.states],
                            dtype=t.dtype, device=t.device)
        run = lambda models, step, n, keep=None: simulate(
            spec, models, t[:n], {u: (v if keep is None else v[keep])[..., :n] for u, v in inputs.items()},
            {x: v if keep is None else v[keep] for x, v in initial.items()}, method=options.solver, step=step,
            rtol=options.rtol, atol=atol, scale=scale, held=held.get(group[0], ()))
        if auto:  # the run at twice the step agrees, or the step is halved
            points = torch.cat([torch.arange(o, o + 3) for o in torch.tensor([0] + sizes[:-1]).cumsum(0).tolist()])
            spread = {x: torch.cat([views[label][x].std().expand(3, 1) for label in group]) for x in spec.states}
            spanned = lambda step: max(2, int((t <= t[0] + CHECK_STEPS * step).sum()))
            check = lambda step, n: run([_pick(m, points) for m in batch], step, n, points)

            def agreement(coarse, fine, n):
                reference = {x: torch.cat([views[label][x][:n].expand(3, -1) for label in group]) for x in spec.states}
                return converged(coarse, fine, scale, _off(fine, reference, spread))

            n = spanned(step)
            whole = n == t.shape[0]  # the check spans the record: its fine runs are the free runs
            fine = lambda step: run(batch, step, n) if whole else check(step, n)
            at_points = lambda runs: {x: v[points] for x, v in runs.items()} if whole else runs
            coarse, runs = check(2 * step, n), fine(step)
            for halving in range(HALVINGS + 1):
                agree = agreement(coarse, at_points(runs), n)
                if bool(agree.all()) or halving == HALVINGS:
                    break
                coarse, step = at_points(runs), step / 2
                runs = fine(step)
            trajectory = runs if whole else None
            while not whole and halving == 0 and _doubles(step, dt, widest):  # agreed at once: the step is
                n = spanned(2 * step)  # doubled while the runs at it and at twice it agree
                if not bool(agreement(check(4 * step, n), check(2 * step, n), n).all()):
                    break
                step = 2 * step
        if trajectory is None:
            trajectory = run(batch, step, t.shape[0])
        for k, label in enumerate(group):
            settled = agree[3 * k:3 * k + 3].tolist()
            steps[label] = {"method": options.solver, "step": step, "converged": all(settled) and not stiff,
                            "unconverged": [m for m, ok in zip(measures.MODELS, settled) if not ok or stiff],
                            **({} if fixed else {"rtol": options.rtol, "atol": options.atol})}
        offsets = [0] + torch.tensor(sizes).cumsum(0).tolist()
        for k, label in enumerate(group):
            result[label] = {x: v[offsets[k]:offsets[k + 1]] for x, v in trajectory.items()}
    return result, steps


def _doubles(step: float, dt: float, widest: float) -> bool:
    """Whether a checked fixed ``step`` may be tried at twice its length: within ``widest`` (the
    record's share and the stability bound of :func:`_first_step`), and four times it divides the
    sample period ``dt``: the check's run at twice the doubled step meets every sample (a held
    input's switches) at a step's end and reads the input unfiltered (:func:`anti_aliased`)."""
    ratio = dt / (4 * step)
    return 2 * step <= widest * (1 + 1e-9) and ratio >= 1 - 1e-9 and abs(ratio - round(ratio)) < 1e-6


def _first_step(spec: ModelSpec, sets: dict, batches: dict, starts: dict, method: str, band: float,
                t: torch.Tensor, held: bool = False) -> tuple[float, bool, float]:
    """A fixed step's start: :data:`PER_PERIOD` of the band's period, at most 1/:data:`STEPS` of the
    record and half :data:`STABLE_SHARE` of the step the fastest decaying mode of the three point
    models allows (:func:`~msam_torch.simulation.equations.fastest_decay` along the records: the
    check's run at twice the step is stable too), at
    least 1/:data:`STIFF_SUBSTEPS` of the sample period (below it the models are too stiff for a
    fixed step: the second value); below the sample period, its nearest divisor, so that a held
    input switches between steps. Where the records hold an input (``held``), at most half the
    sample period and an even divisor of it: the check's run at twice the step, too, meets every
    switch at a step's end. The third value is the widest step the check may double it to
    (:func:`_doubles`): the bounds but the band's."""
    dt = float(t[1] - t[0])
    decay = max(float(fastest_decay(spec, [_first(m, 3) for m in batches[label]],
                                    _points(spec, sets[label], starts.get(label))).max()) for label in sets)
    stable = STABLE_SHARE * STABILITY[method] / (2 * decay) if decay > 0 else math.inf  # the check's run at 2 h too
    widest = min(float(t[-1] - t[0]) / STEPS, stable)
    step = min(widest, PER_PERIOD / band)
    stiff = step < dt / STIFF_SUBSTEPS
    step = max(step, dt / STIFF_SUBSTEPS)
    if held:
        return dt / (2 * math.ceil(dt / (2 * step))), stiff, widest
    return (dt / round(dt / step) if step < dt else step), stiff, widest


def _points(spec: ModelSpec, dataset, start: dict | None) -> dict:
    """:data:`MODES_AT` evenly spaced samples of the time, every state (from ``start``, the
    diagnosis's view of the record, where it holds it) and every input of ``dataset``."""
    def sampled(v):
        return v[torch.linspace(0, v.shape[-1] - 1, MODES_AT, device=v.device).round().long()]
    view = {**dataset.signals, **(start or {})}
    return {name: sampled(view[name]) for name in ("t", *spec.states, *spec.inputs) if name in view}


def _first_sample(state: str, *views: dict | None) -> torch.Tensor:
    """A state's first sample in the first of ``views`` (signal mappings) that holds it."""
    for view in views:
        if view and state in view:
            return view[state][0]
    raise MSAMError(f"cannot start a free run: the data give no value of state {state!r} "
                    "(measure it or a lower derivative of it, or pass --no-free-run)")


def anti_aliased(signal: torch.Tensor, dt: float, step: float) -> torch.Tensor:
    """An input as a fixed-step solver stepping over samples sees it: low-passed at the Nyquist
    frequency of ``step`` (zero-phase Butterworth, order 4), so that runs at different steps read
    the same input and differ only by their integration error; unchanged when ``step`` <= ``dt``."""
    if step <= dt * (1 + 1e-9):
        return signal
    filtered = zero_phase(butterworth(4, dt / step), signal.detach().cpu().double().numpy())
    return torch.as_tensor(filtered, dtype=signal.dtype, device=signal.device)


def _off(runs: dict, reference: dict, spread: dict) -> torch.Tensor:
    """Members (B,) whose run leaves the record by more than :data:`DIVERGED` of a state's
    standard deviation (RMS over the run), or is not finite. Like a run that is NaN at both steps
    they are reported diverged and not halved for, even where only the step is too long for them
    (a stiff model under a fixed step)."""
    first = next(iter(runs.values()))
    off = torch.zeros(first.shape[0], dtype=torch.bool, device=first.device)
    for x, v in runs.items():
        deviation = (v - reference[x]).square().mean(-1, keepdim=True).sqrt()
        off |= ~(deviation <= DIVERGED * spread[x]).squeeze(-1)
    return off


def converged(coarse: dict, fine: dict, scale: dict, off: torch.Tensor | None = None) -> torch.Tensor:
    """Members (B,) whose runs at two steps agree: RMS difference within :data:`AGREEMENT` of each
    state's measured magnitude, diverged (NaN) in both or in neither; members ``off`` (B,) the
    record in the fine run (:func:`_off`) are not checked (they agree)."""
    agree = None
    for x, a in coarse.items():
        b = fine[x]
        both = torch.isfinite(a) & torch.isfinite(b)
        difference = torch.where(both, a - b, torch.zeros_like(a)).square().mean(-1).sqrt()
        ok = (torch.isnan(a).all(-1) == torch.isnan(b).all(-1)) & \
            (difference <= AGREEMENT * max(scale[x], torch.finfo(a.dtype).tiny))
        agree = ok if agree is None else agree & ok
    return agree if off is None else agree | off


def _pick(model: EquationModel, rows: torch.Tensor) -> EquationModel:
    return EquationModel(model.equation, model.choice[rows], model.gamma[rows], model.theta[rows],
                         model.theta_fixed[rows], model.scale)


def _concat(models: list[EquationModel]) -> EquationModel:
    if len(models) == 1:
        return models[0]
    cat = lambda name: torch.cat([getattr(m, name) for m in models])
    return EquationModel(models[0].equation, cat("choice"), cat("gamma"), cat("theta"), cat("theta_fixed"), models[0].scale)


def _first(model: EquationModel, b: int) -> EquationModel:
    return _pick(model, torch.arange(b))
