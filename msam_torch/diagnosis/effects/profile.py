"""The threshold of each threshold form (:mod:`.thresholds`), profiled on its grid and given an
interval by block-bootstrap trials: all grid values of all forms fitted as one batch, the grid on
the trials' axis (each form's threshold a name whose value differs per trial), the hypotheses'
own step fitting theta and a hinge's exponent (:func:`~.hypotheses.fit`)."""
from __future__ import annotations

from dataclasses import replace

import torch

from msam_torch.diagnosis.effects.bootstrap import block_weights
from msam_torch.diagnosis.effects.hypotheses import (
    Fitted,
    Hypothesis,
    encode,
    extended_equation,
    fit,
    predict_rows,
    threshold_hypotheses,
)
from msam_torch.diagnosis.effects.thresholds import Threshold, grids, spread, switchable
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.stages.rows import WeakForm
from msam_torch.engine.values import StepOptions
from msam_torch.model.spec import Equation
from msam_torch.run.estimation import Estimation


def profile(equation: Equation, found: list[Threshold], estimation: Estimation, options: DiagnoseOptions,
            step_options: StepOptions, generator: torch.Generator) -> list[Threshold]:
    """Each form of ``found`` at the grid value that fits the training rows best (Eq. 19; a hinge's
    exponent fitted by ``options.bootstrap_steps`` steps at every grid value), with its
    ``half_width`` from ``options.bootstrap`` block-bootstrap trials: each trial's grid value of
    least squared error on its block-weighted rows, the fit's theta and exponent held
    (:func:`~.thresholds.spread`); ``generator`` seeds the trials' own generator (it draws nothing
    from it)."""
    if not found:
        return []
    symbolic = [replace(f, symbol=f"threshold_{k}") for k, f in enumerate(found)]
    levels = grids(found, estimation.train)  # (G, K)
    prepared = switchable(equation, symbolic)
    hypotheses = [Hypothesis("retuned")] + threshold_hypotheses(prepared, symbolic)
    grid_size = levels.shape[0]
    with_levels = lambda signals: None if signals is None else {  # every signal on the grid's axis
        **{n: v if n == "t" else v.expand(grid_size, -1) for n, v in signals.items()},
        **{f.symbol: levels[:, k:k + 1].to(signals["t"]).expand(-1, signals["t"].shape[-1])
           for k, f in enumerate(symbolic)}}
    weak = WeakForm.build(extended_equation(prepared, None, symbolic), with_levels(estimation.train),
                          with_levels(estimation.held_out), estimation.half_width, options.blocks)
    choices, starts = encode(prepared, hypotheses, weak.signals["t"].device)
    q = len(prepared.adjustable)
    stepped = torch.tensor([h.has_exponent for h in hypotheses])  # a clip or dead zone needs theta alone
    fitted = _merged([(rows, fit(weak.data, choices[rows], starts[rows], step_options, steps, q))
                      for rows, steps in ((stepped, options.bootstrap_steps), (~stepped, 0)) if bool(rows.any())],
                     len(hypotheses))
    score = torch.where(fitted.invalid, torch.full_like(fitted.fitness, -torch.inf), fitted.fitness)  # (G, 1 + K)
    best = score[:, 1:].argmax(0)  # (K,)
    spans = [float(estimation.train[f.signal].max() - estimation.train[f.signal].min()) for f in found]
    values = [float(levels[best[k], k]) for k in range(len(found))]
    if options.bootstrap <= 0:
        return [replace(f, value=v, span=s) for f, v, s in zip(found, values, spans)]
    trials = torch.Generator().manual_seed(generator.initial_seed() + 1)
    weights = block_weights(weak.fit_rows, options.bootstrap, options.blocks, trials)  # (B, M)
    squared = (predict_rows(weak.data, choices, fitted) - weak.data.y.unsqueeze(1)).square()  # (G, 1 + K, M)
    sse = torch.where(fitted.invalid.unsqueeze(-1), torch.inf, squared)[:, 1:] @ weights.T  # (G, K, B)
    chosen = levels.gather(0, sse.argmin(0).T)  # (B, K): each trial's best grid value
    step = lambda k: float(levels[1, k] - levels[0, k])
    return [replace(f, value=v, span=s, half_width=spread(chosen[:, k].tolist(), v, step(k)))
            for k, (f, v, s) in enumerate(zip(found, values, spans))]



def _merged(parts: list, c: int) -> Fitted:
    """The fits of disjoint sets of hypotheses (mask (C,), :class:`~.hypotheses.Fitted`) as one of all ``c``."""
    first = parts[0][1]

    def field(name):
        sample = getattr(first, name)
        out = sample.new_empty(sample.shape[:1] + (c,) + sample.shape[2:])
        for rows, part in parts:
            out[:, rows.to(out.device)] = getattr(part, name)
        return out
    return Fitted(*(field(n) for n in ("gamma", "theta", "theta_fixed", "fitness", "invalid")))
