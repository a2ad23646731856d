"""State and derivative estimation from sampled signals, with well-kept library code.

Estimators (all return the smoothed signal and its first ``order`` derivatives):
- ``savgol``: Savitzky-Golay (``scipy.signal.savgol_filter``), cubic, the default;
- ``spline``: penalised smoothing spline (``scipy.interpolate.make_smoothing_spline``, GCV);
- ``loess``: locally weighted regression (statsmodels ``lowess``, the paper's choice), then a
  cubic interpolating spline for the derivatives;
- ``finite_difference``: no smoothing, second-order central differences (``numpy.gradient``).
Sampling must be uniform for ``savgol`` and ``finite_difference``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import DataError

METHODS = ("savgol", "spline", "loess", "finite_difference")


@dataclass(frozen=True)
class Estimate:
    """``values[k]`` is the k-th derivative (k = 0 is the smoothed signal)."""

    values: list[np.ndarray]
    method: str
    window: int | None

    @property
    def info(self) -> dict:
        return {"method": self.method, "window": self.window}


def default_window(n: int, order: int) -> int:
    """An odd Savitzky-Golay window: about 2 % of the record, at least enough for the order."""
    window = max(2 * (order + 2) + 1, int(0.02 * n) | 1)
    return window


def estimate(t: np.ndarray, y: np.ndarray, order: int, method: str = "savgol", window: int | None = None,
             name: str = "signal") -> Estimate:
    """Smooth ``y(t)`` and estimate derivatives up to ``order``; errors name ``name``."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    if method not in METHODS:
        raise DataError(f"{name}: unknown derivative estimator {method!r} (known: {', '.join(METHODS)})")
    if method == "finite_difference":
        if n < order + 2:
            raise DataError(f"{name}: {n} samples are too few for a derivative of order {order}")
        values = [y]
        for _ in range(order):
            values.append(np.gradient(values[-1], t, edge_order=2))
        return Estimate(values, method, None)
    if method == "savgol":
        from scipy.signal import savgol_filter

        window = default_window(n, order) if window is None else window
        if window % 2 == 0:
            window += 1
        polyorder = min(3, window - 1)
        if polyorder < order:
            polyorder = order
        if n < window or window <= polyorder:
            raise DataError(f"{name}: {n} samples are fewer than the derivative window of {window} samples "
                            f"(set data.window smaller, at least {polyorder + 1 + (polyorder % 2 == 0)})")
        dt = float(np.median(np.diff(t)))
        values = [savgol_filter(y, window, polyorder, deriv=k, delta=dt, mode="interp") for k in range(order + 1)]
        return Estimate(values, method, window)
    if method == "spline":
        from scipy.interpolate import make_smoothing_spline

        if n < 5:
            raise DataError(f"{name}: {n} samples are too few for a smoothing spline (need 5)")
        spline = make_smoothing_spline(t, y)
        return Estimate([spline(t, nu=k) for k in range(order + 1)], method, None)
    from scipy.interpolate import CubicSpline
    from statsmodels.nonparametric.smoothers_lowess import lowess

    window = default_window(n, order) if window is None else window
    if n < max(window, 4):
        raise DataError(f"{name}: {n} samples are fewer than the LOESS window of {window} samples")
    smooth = lowess(y, t, frac=min(1.0, window / n), it=0, return_sorted=False)
    spline = CubicSpline(t, smooth)
    return Estimate([smooth] + [spline(t, nu=k) for k in range(1, order + 1)], method, window)


def noise_level(y: np.ndarray) -> float:
    """Rough standard deviation of white measurement noise from third differences.

    ``diff(y, 3)`` of a smooth signal is ~0, and of white noise has variance ``20 sigma^2``.
    """
    y = np.asarray(y, dtype=float)
    if y.size < 5:
        return float("nan")
    d = np.diff(y, 3)
    mad = np.median(np.abs(d - np.median(d))) * 1.4826
    return float(mad / np.sqrt(20.0))
