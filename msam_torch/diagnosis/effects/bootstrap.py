"""Bootstrap trials of the hypothesis fit: moving time blocks of the weak-form rows and noise on
their targets, all trials fitted as one batch on the leading axis, warm-started at the original
fit (the best effect hypotheses and the re-fitted start only). Beside them, copies of the
whole record with measurement noise added again to every measured state the rows read: noise in a
regressor moves a non-linear law's exponent (errors in variables), and about as far again when
the noise power is doubled: a shift no spread of the trials shows (:func:`~msam_torch.diagnosis.catalogue.naming.half_width`)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from msam_torch.diagnosis.effects.hypotheses import Fitted, fit, heldout_errors, heldout_rmse, sane
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.stages.rows import WeakForm
from msam_torch.engine.candidates import EquationData
from msam_torch.engine.values import StepOptions


@dataclass(frozen=True)
class Bootstrap:
    """The trials' weighted rows, fits of every hypothesis (T, C) and held-out RMSE (T, C); the
    hypotheses not re-fitted are invalid with RMSE inf."""

    data: EquationData
    fitted: Fitted
    rmse: torch.Tensor
    noisier: Fitted  # (copies, C): the fits to the record with its measured states' noise doubled


def block_weights(fit_rows: torch.Tensor, trials: int, blocks: int, generator: torch.Generator) -> torch.Tensor:
    """Moving-block bootstrap as weights (trials, M): ``blocks`` contiguous row blocks of the fitted
    rows are drawn with replacement; a row's weight counts how often its block was drawn."""
    m = fit_rows.shape[0]
    block_of = torch.div(torch.arange(m) * blocks, m, rounding_mode="floor")
    draws = torch.randint(0, blocks, (trials, blocks), generator=generator)
    counts = torch.zeros(trials, blocks, dtype=torch.float64).scatter_add_(1, draws, torch.ones(trials, blocks, dtype=torch.float64))
    return counts[:, block_of].to(fit_rows.device) * fit_rows.to(torch.float64)


def bootstrap(weak: WeakForm, choices: torch.Tensor, q: int, original: Fitted, rmse: torch.Tensor, noise: float,
              order: int, again: Callable[[int], dict], options: DiagnoseOptions, step_options: StepOptions,
              generator: torch.Generator) -> Bootstrap | None:
    """``options.bootstrap`` trials (None for none) of the hypotheses' ``choices`` (``q`` adjustable
    components, :func:`~.hypotheses.fit`): row weights from :func:`block_weights`, target noise of
    the measured signal's level ``noise`` integrated against the order-``order`` test function;
    and half as many copies of every row with ``again(copies)`` (signal -> (copies, N)) added to
    the measured states. Each re-fits the re-fitted start and the ``options.bootstrap_hypotheses``
    best valid effect hypotheses (by held-out ``rmse``, (C,)) whose exponents are sane (the ones that
    can be named), ``options.bootstrap_steps`` steps from the original fit."""
    if options.bootstrap <= 0:
        return None
    t = weak.signals["t"]
    weights = block_weights(weak.fit_rows, options.bootstrap, options.blocks, generator)
    row_noise = noise * float(torch.linalg.vector_norm(weak.tests.kernels[order]))
    jitter = row_noise * torch.randn(options.bootstrap, weak.rows, generator=generator, dtype=t.dtype).to(t.device)
    data = weak.weighted(weights, jitter)
    is_sane = sane(original)[0]
    effects = [int(c) for c in torch.argsort(rmse) if c != 0 and torch.isfinite(rmse[c]) and is_sane[c]]
    keep = torch.tensor([0] + effects[:options.bootstrap_hypotheses], device=t.device)
    part = fit(data, choices[keep], original.gamma[:, keep], step_options, options.bootstrap_steps, q)
    boot_rmse = torch.full((options.bootstrap, choices.shape[0]), torch.inf, dtype=t.dtype, device=t.device)
    boot_rmse[:, keep] = heldout_rmse(heldout_errors(weak.val_data, weak.val_rows, choices[keep], part), part)
    every_row = weak.fit_rows.to(t.dtype).unsqueeze(0)
    copies = weak.weighted(every_row, noise=again(max(2, options.bootstrap // 2)))
    noisier = fit(copies, choices[keep], original.gamma[:, keep], step_options, options.bootstrap_steps, q)
    c = choices.shape[0]
    return Bootstrap(data, _scatter(part, keep, c), boot_rmse, _scatter(noisier, keep, c))


def _scatter(part: Fitted, keep: torch.Tensor, c: int) -> Fitted:
    """Bootstrap results of the hypotheses ``keep`` placed among all ``c`` (others invalid)."""
    def full(x, fill):
        out = torch.full((x.shape[0], c) + x.shape[2:], fill, dtype=x.dtype, device=x.device)
        out[:, keep] = x
        return out
    return Fitted(full(part.gamma, 0.0), full(part.theta, 0.0), full(part.theta_fixed, 0.0),
                  full(part.fitness, -torch.inf), full(part.invalid, True))
