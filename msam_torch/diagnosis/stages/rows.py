"""The weak-form rows of one state equation for the diagnosis: training rows and held-out rows
(:class:`WeakForm`); the form itself is :mod:`msam_torch.engine.weak_form`."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from msam_torch.engine.candidates import EquationData
from msam_torch.engine.weak_form import TestFunctions, weak_data
from msam_torch.model.spec import Equation


@dataclass(frozen=True)
class WeakForm:
    """The weak-form rows of one (extended) equation: training rows (``data``, weighted 0/1 by
    ``fit_rows``) and held-out rows (``val_data`` at ``val_rows``), F normalised by the training
    RMS ``scale``."""

    extended: Equation
    signals: dict
    tests: TestFunctions
    scale: torch.Tensor
    fit_rows: torch.Tensor
    data: EquationData
    val_signals: dict
    val_tests: TestFunctions
    val_rows: torch.Tensor
    val_data: EquationData

    @classmethod
    def build(cls, extended: Equation, train: dict, held_out: dict | None, half_width: float,
              blocks: int) -> "WeakForm":
        """Rows of the ``train`` (and ``held_out``) signals (:mod:`msam_torch.run.estimation` prepares them);
        test functions of ``half_width`` time units; without held-out signals, alternate ones of
        ``blocks`` time blocks of the training rows are held out."""
        signals = train
        t = signals["t"]
        tests = TestFunctions.spanning(t, half_width)
        m = tests.count(t.shape[0])
        scale = EquationData.build(extended, signals, "rms").scale[0]
        if held_out is not None:
            val_signals = held_out
            val_tests = TestFunctions.spanning(val_signals["t"], half_width)
            fit_rows = torch.ones(m, dtype=torch.bool, device=t.device)
            val_data = weak_data(extended, val_signals, val_tests, scale)
            val_rows = torch.ones(val_data.y.shape[-1], dtype=torch.bool, device=t.device)
        else:
            block = torch.div(torch.arange(m, device=t.device) * blocks, m, rounding_mode="floor")
            fit_rows = block % 2 == 0
            val_tests, val_signals, val_rows = tests, signals, ~fit_rows
            val_data = weak_data(extended, signals, tests, scale)
        data = weak_data(extended, signals, tests, weights=fit_rows.to(t.dtype).unsqueeze(0))
        return cls(extended, signals, tests, scale, fit_rows, data, val_signals, val_tests, val_rows, val_data)

    @property
    def rows(self) -> int:
        return self.fit_rows.shape[0]

    @property
    def y_val(self) -> torch.Tensor:
        """The held-out rows' targets (M',)."""
        return self.val_data.y[0][self.val_rows]

    def apart(self, reach: int = 0, tests: TestFunctions | None = None) -> int:
        """Rows (held out, or of ``tests``) apart by which their errors are independent under white
        measurement noise: the test functions' length plus ``reach`` samples (the window of a
        derivative estimate)."""
        tests = self.val_tests if tests is None else tests
        return math.ceil((tests.kernels.shape[-1] + reach) / tests.stride)

    def independent_rows(self, reach: int = 0) -> int:
        """How many held-out rows :meth:`apart` from each other there are."""
        return -(-int(self.val_rows.sum()) // self.apart(reach))

    def folds(self, k: int, reach: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """Blocked ``k``-fold cross-fitting of the training rows (at most a fold per row): ``fold``
        (M,), the block of contiguous fitted rows each row is in (-1: not fitted), and ``weights``
        (k, M), each fold's fit: the fitted rows outside its block and not within :meth:`apart` of
        it (those share its errors), so that every fitted row is predicted once by a fit it took no
        part in."""
        position = torch.arange(self.rows, device=self.fit_rows.device)
        fitted = position[self.fit_rows]
        k = min(k, fitted.numel())
        fold = torch.full_like(position, -1)
        fold[fitted] = torch.div(torch.arange(fitted.numel(), device=fitted.device) * k, fitted.numel(),
                                 rounding_mode="floor")
        gap = self.apart(reach, self.tests)
        weights = []
        for j in range(k):
            inside = position[fold == j]
            far = (position <= int(inside.min()) - gap) | (position >= int(inside.max()) + gap)
            weights.append(self.fit_rows & far)
        return fold, torch.stack(weights).to(self.signals["t"].dtype)

    def independence(self, reach: int = 0) -> tuple[int, int]:
        """How many held-out rows and how many fitted training rows :meth:`apart` from each other there are."""
        return self.independent_rows(reach), -(-int(self.fit_rows.sum()) // self.apart(reach, self.tests))

    @property
    def target_rms(self) -> float:
        return float(torch.sqrt((self.y_val**2).mean()))

    def weighted(self, weights: torch.Tensor, jitter: torch.Tensor | None = None,
                 noise: dict | None = None) -> EquationData:
        """The training rows weighted by ``weights`` (T, M), targets moved by ``jitter`` (T, M), of
        the signals with ``noise`` (signal -> (T, N)) added."""
        signals = {**self.signals, **{k: self.signals[k] + v for k, v in (noise or {}).items()}}
        return weak_data(self.extended, signals, self.tests, weights=weights, jitter=jitter)
