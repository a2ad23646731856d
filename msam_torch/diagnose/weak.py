"""Weak (integral) form of a state equation: integrate against smooth test functions.

``int phi_m(t) y^(k)(t) dt = (-1)^k int phi_m^(k)(t) y(t) dt`` for test functions that vanish with
their derivatives at the window ends, so the target needs no numerical derivative of the data,
and every regressor is filtered by the same kernel ``phi_m`` (consistent regressors, design.md
section 3; weak SINDy, Messenger and Bunch 2021). The test functions are bumps
``phi(s) = (1 - s^2)^p``, ``s = (t - c_m)/h``, centred every ``stride`` samples on a uniform grid.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import comb

import torch

from ..errors import DataError

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
