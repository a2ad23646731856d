"""Weak (integral) form of a state equation: integrate against smooth test functions
(:class:`TestFunctions`), and the rows of one equation in that form (:func:`weak_data`).

``int phi_m(t) y^(k)(t) dt = (-1)^k int phi_m^(k)(t) y(t) dt`` for test functions that vanish with
their derivatives at the window ends, so the target needs no numerical derivative of the data,
and every regressor is filtered by the same kernel ``phi_m`` (consistent regressors, docs/design.md
section 3; weak SINDy, Messenger and Bunch 2021): a non-linearity's harmonics that a smoother
removes from an estimated derivative stay in the regressors it is compared with, and bias the
exponents; the weak form filters both sides alike. The test functions are bumps
``phi(s) = (1 - s^2)^p``, ``s = (t - c_m)/h``, centred every ``stride`` samples on a uniform grid;
their half-width comes from the band the record occupies (:func:`half_width_for`: time units of
the system, not a share of the record; :mod:`msam_torch.run.estimation` prepares the signals). ``adapt``
uses the form with ``adaptation.form: weak``, and with ``auto`` (the measured-data preset's) where
:func:`resolves` holds; the diagnosis always.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from math import comb

import torch

from msam_torch.engine.candidates import FLOOR, EquationData
from msam_torch.errors import DataError
from msam_torch.model.spec import Equation, split_derivative

HALF_AMPLITUDE = 0.6  # f h at which the bump (1 - s^2)^4 of half-width h passes half the amplitude
SHORTEST = 4  # samples in a test function's half-width, at least
WIDEST = 0.1  # of the record: a test function's half-width, at most

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

    @classmethod
    def spanning(cls, t: torch.Tensor, half_width: float) -> "TestFunctions":
        """Test functions of ``half_width`` time units (at least :data:`SHORTEST` samples) on ``t``."""
        return cls.build(t, max(SHORTEST, round(half_width / float(t[1] - t[0]))))

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
              weights: torch.Tensor | None = None, jitter: torch.Tensor | None = None,
              normalize: str = "functions") -> EquationData:
    """Weak-form data of one equation (signals (N,) or (T, N)); F normalised as ``normalize``
    (:meth:`EquationData.build`) or by the training ``scale``; rows weighted by ``weights``
    (T, M), targets moved by ``jitter`` (T, M)."""
    data = EquationData.build(extended, signals, normalize if scale is None else "none")
    if scale is not None:
        data = replace(data, log_f=(data.log_f - scale.log()).clamp_min(torch.log(torch.tensor(FLOOR))),
                       scale=scale.unsqueeze(0))
    source, order = target_source(extended, signals)
    values = signals[source] if signals[source].dim() == 2 else signals[source].unsqueeze(0)
    y = (-1) ** order * tests.integrate_signal(values, order)  # (T, M)
    if jitter is not None:
        y = y + jitter
    fixed = tests.integrate(data.fixed_components)
    root = None if weights is None else weights.sqrt()
    if root is not None:
        y, fixed = y * root, fixed * root.unsqueeze(-1)
    return replace(data, y=y, fixed_components=fixed, project=Projection(tests, root))


def half_width_for(band: float, t, given: float | None = None) -> float:
    """Test-function half-width (time units) that passes ``band`` (cycles per time unit) at half
    amplitude (or ``given``), kept between :data:`SHORTEST` samples and :data:`WIDEST` of the
    record ``t``."""
    dt, record = float(t[1] - t[0]), float(t[-1] - t[0])
    return min(max(given or HALF_AMPLITUDE / band, SHORTEST * dt), WIDEST * record)


def resolves(band: float) -> bool:
    """Whether test functions of :data:`SHORTEST` samples or more pass ``band`` (cycles per sample)
    at half amplitude: whether the record is sampled finely enough for the weak form's quadrature."""
    return HALF_AMPLITUDE / band >= SHORTEST
