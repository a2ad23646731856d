"""Weak (integral) form of a state equation: integrate against smooth test functions; the
weak-form rows of one equation for fitting and for held-out scoring (:class:`WeakForm`).

``int phi_m(t) y^(k)(t) dt = (-1)^k int phi_m^(k)(t) y(t) dt`` for test functions that vanish with
their derivatives at the window ends, so the target needs no numerical derivative of the data,
and every regressor is filtered by the same kernel ``phi_m`` (consistent regressors, docs/design.md
section 3; weak SINDy, Messenger and Bunch 2021). The test functions are bumps
``phi(s) = (1 - s^2)^p``, ``s = (t - c_m)/h``, centred every ``stride`` samples on a uniform grid.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from math import comb

import torch

from ..candidates import FLOOR, EquationData
from ..errors import DataError
from ..spec import Equation, split_derivative

POWER = 4  # phi and its first three derivatives vanish at the window ends


@dataclass(frozen=True)
class TestFunctions:
    """Bump test functions on a uniform grid; ``kernels[k]`` holds ``phi^(k)(t_j) dt`` over a window."""

    half_width: int  # samples
    stride: int
    dt: float
    kernels: torch.Tensor  # (orders + 1, 2 * half_width + 1)

    @classmethod
    def build(cls, t: torch.Tensor, half_width: int, stride: int | None = None, orders: int = 2) -> "TestFunctions":
        n = t.shape[-1]
        if n < 2 * half_width + 1:
            raise DataError(f"{n} samples are fewer than one test-function window of {2 * half_width + 1} samples "
                            "(set a smaller 'half_width')")
        dt = float(t[1] - t[0])
        h = half_width * dt
        s = torch.linspace(-1.0, 1.0, 2 * half_width + 1, dtype=t.dtype, device=t.device)
        # (1 - s^2)^p = sum_j C(p, j) (-1)^j s^(2j); differentiate the polynomial term by term.
        coefficients = torch.zeros(2 * POWER + 1, dtype=t.dtype)
        for j in range(POWER + 1):
            coefficients[2 * j] = comb(POWER, j) * (-1) ** j
        kernels = []
        for k in range(orders + 1):
            values = sum(float(c) * s**e for e, c in enumerate(coefficients.tolist()) if c != 0)
            kernels.append(values * dt / h**k)
            coefficients = torch.tensor([e * c for e, c in enumerate(coefficients.tolist())][1:] + [0.0], dtype=t.dtype)
        return cls(half_width, stride or max(1, half_width // 2), dt, torch.stack(kernels).to(t.device))

    def count(self, n: int) -> int:
        return (n - (2 * self.half_width + 1)) // self.stride + 1

    def integrate(self, values: torch.Tensor, order: int = 0) -> torch.Tensor:
        """``int phi_m^(order) v dt`` along the sample axis -2: (..., N, Q) -> (..., M, Q)."""
        windows = values.unfold(-2, self.kernels.shape[-1], self.stride)  # (..., M, Q, L)
        return windows @ self.kernels[order].to(values.dtype)

    def integrate_signal(self, signal: torch.Tensor, order: int = 0) -> torch.Tensor:
        """The same for a signal (..., N) -> (..., M)."""
        return self.integrate(signal.unsqueeze(-1), order).squeeze(-1)

    def average(self, signal: torch.Tensor) -> torch.Tensor:
        """Kernel-weighted mean of a signal over each window (..., M): the state a row describes."""
        return self.integrate_signal(signal) / self.kernels[0].sum()


def target_source(equation: Equation, signals: dict) -> tuple[str, int]:
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


def weak_data(extended: Equation, signals: dict, tests: TestFunctions, scale: torch.Tensor | None = None,
              weights: torch.Tensor | None = None, jitter: torch.Tensor | None = None) -> EquationData:
    """Weak-form data of one equation; ``scale`` reuses the training normalisation of F; rows
    weighted by ``weights`` (T, M), targets moved by ``jitter`` (T, M)."""
    data = EquationData.build(extended, signals, "functions" if scale is None else "none")
    if scale is not None:
        data = replace(data, log_f=(data.log_f - scale.log()).clamp_min(torch.log(torch.tensor(FLOOR))),
                       scale=scale.unsqueeze(0))
    source, order = target_source(extended, signals)
    y = (-1) ** order * tests.integrate_signal(signals[source].unsqueeze(0), order)  # (1, M)
    if jitter is not None:
        y = y + jitter
    fixed = tests.integrate(data.fixed_components)
    root = None if weights is None else weights.sqrt()
    if root is not None:
        y, fixed = y * root, fixed * root.unsqueeze(-1)
    return replace(data, y=y, fixed_components=fixed, project=Projection(tests, root))


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
        """Rows of the ``train`` (and ``held_out``) signals (:mod:`.estimation` prepares them);
        test functions of ``half_width`` time units; without held-out signals, alternate ones of
        ``blocks`` time blocks of the training rows are held out."""
        signals = train
        t = signals["t"]
        tests = TestFunctions.build(t, max(4, round(half_width / float(t[1] - t[0]))))
        m = tests.count(t.shape[0])
        scale = EquationData.build(extended, signals, "rms").scale[0]
        if held_out is not None:
            val_signals = held_out
            val_dt = float(val_signals["t"][1] - val_signals["t"][0])
            val_tests = TestFunctions.build(val_signals["t"], max(4, round(half_width / val_dt)))
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

    @property
    def target_rms(self) -> float:
        return float(torch.sqrt((self.y_val**2).mean()))

    def weighted(self, weights: torch.Tensor, jitter: torch.Tensor) -> EquationData:
        """The training rows weighted by ``weights`` (T, M), targets moved by ``jitter`` (T, M)."""
        return weak_data(self.extended, self.signals, self.tests, weights=weights, jitter=jitter)
