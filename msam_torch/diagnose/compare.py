"""Comparison of models: the starting, theta-retuned and adapted models (and every bootstrap
trial's retuned and adapted pair) one-step and in free run (:mod:`msam_torch.simulation`) on the
training and held-out data, with the part of the gap each closes (:mod:`.measures`)."""
from __future__ import annotations

import torch

from ..simulation import EquationModel, simulate_equations as simulate
from ..spec import Equation, ModelSpec
from . import measures
from .bootstrap import Bootstrap
from .confidence import best_effect
from .hypotheses import Fitted
from .options import DiagnoseOptions


def models(extended: Equation, equation: Equation, nominal: torch.Tensor, choices: torch.Tensor, original: Fitted,
           boot: Bootstrap | None, winner: int, is_effect: torch.Tensor, scale: torch.Tensor) -> EquationModel:
    """Extended-form models batched as [start, retuned, adapted, (retuned, adapted) per bootstrap trial]."""
    q = len(equation.adjustable)
    start_theta = torch.cat([nominal[list(equation.adjustable)], nominal.new_zeros(q)])
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


def compare(spec: ModelSpec, models: list[EquationModel], train, held_out, series: dict, options: DiagnoseOptions) -> dict:
    """One-step and free-run measures of the three models on training and held-out data; the
    arrays the plots draw are added to ``series`` (per target).

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


def _simulate_sets(spec: ModelSpec, sets: dict, batches: dict, options: DiagnoseOptions) -> dict:
    """Free runs from each set's first (estimated) state under its inputs; sets on the same time
    grid are integrated in one batch."""
    grids = {label: d.signals["t"] for label, d in sets.items()}
    same = len(sets) == 2 and grids["train"].shape == grids["held_out"].shape and torch.allclose(
        grids["train"], grids["held_out"])
    groups = [list(sets)] if same else [[label] for label in sets]
    result = {}
    for group in groups:
        sizes = [batches[label][0].choice.shape[0] for label in group]
        batch = [_concat([batches[label][e] for label in group]) for e in range(len(batches[group[0]]))]
        inputs = {u: torch.cat([sets[label].signals[u].expand(n, -1) for label, n in zip(group, sizes)])
                  for u in spec.inputs}
        initial = {x: torch.cat([sets[label].signals[x][0].expand(n) for label, n in zip(group, sizes)]) for x in spec.states}
        scale = {x: max(float(sets[label].signals[x].abs().max()) for label in group) for x in spec.states}
        trajectory = simulate(spec, batch, grids[group[0]], inputs, initial, method=options.solver,
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
