"""The digital filters a diagnosis applies to records, as ``scipy.signal`` defines them, computed with
NumPy: importing ``scipy.signal`` alone takes about half a second (its functions' docstrings are
rewritten at import), a third of a diagnosis from the shell.

- :func:`lowpass`: a windowed-sinc FIR low-pass, ``scipy.signal.firwin``;
- :func:`resample`: upsample, FIR-filter and downsample with the ends extended along the line
  through the first and last samples, ``scipy.signal.resample_poly(..., padtype='line')``;
- :func:`savgol`: Savitzky-Golay smoothing and derivatives with polynomial fits at the ends,
  ``scipy.signal.savgol_filter(..., mode='interp')``;
- :func:`butterworth` and :func:`zero_phase`: a Butterworth low-pass as second-order sections,
  applied forwards and backwards from steady state on an odd extension, ``scipy.signal.butter(...,
  output='sos')`` and ``scipy.signal.sosfiltfilt`` (a loop in Python: about a millisecond per
  thousand samples).

They agree with ``scipy.signal`` to rounding (tests/data/test_filters.py).
"""
from __future__ import annotations

from math import factorial

import numpy as np


def lowpass(taps: int, cutoff: float, window: str | tuple = "hamming") -> np.ndarray:
    """FIR low-pass of ``taps`` coefficients at ``cutoff`` (a fraction of the Nyquist frequency):
    the ideal low-pass's sinc through a ``hamming`` or ``("kaiser", beta)`` window, unit gain at 0."""
    m = np.arange(taps) - (taps - 1) / 2
    shape = np.hamming(taps) if window == "hamming" else np.kaiser(taps, window[1])
    h = cutoff * np.sinc(cutoff * m) * shape
    return h / h.sum()


def resample(x: np.ndarray, up: int, down: int, taps: np.ndarray | None = None) -> np.ndarray:
    """``x`` (time on its last axis) resampled by ``up / down``: zeros inserted, filtered by ``taps``
    (default :func:`lowpass` of ``20 max(up, down) + 1`` taps at the lower Nyquist frequency, Kaiser
    window, beta 5) and every ``down``-th sample kept, aligned so that the output's first sample is
    the input's; beyond its ends the input continues along the line through its first and last samples."""
    rate = max(up, down)
    taps = lowpass(20 * rate + 1, 1.0 / rate, ("kaiser", 5.0)) if taps is None else np.asarray(taps, dtype=float)
    half = (taps.size - 1) // 2
    pad = down - half % down
    h = np.concatenate([np.zeros(pad), up * taps])
    n = x.shape[-1]
    first, count = (half + pad) // down, -(-n * up // down)
    low = (first * down - h.size + 1) // up  # the input samples the kept outputs read, line extension included
    high = -(-(first + count - 1) * down // up)
    left, right = max(0, -low), max(0, high - n + 1)
    slope = (x[..., -1:] - x[..., :1]) / max(n - 1, 1)
    extended = np.concatenate([x[..., :1] + slope * np.arange(-left, 0), x,
                               x[..., -1:] + slope * np.arange(1, right + 1)], axis=-1)
    stuffed = np.zeros(extended.shape[:-1] + ((extended.shape[-1] - 1) * up + 1,))
    stuffed[..., ::up] = extended
    rows = stuffed.reshape(-1, stuffed.shape[-1])
    kept = left * up + (first + np.arange(count)) * down
    out = np.stack([np.convolve(row, h)[kept] for row in rows])
    return out.reshape(x.shape[:-1] + (count,))


def savgol(y: np.ndarray, window: int, degree: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """The ``deriv``-th derivative (sample spacing ``delta``) of the least-squares polynomial of
    ``degree`` through each odd ``window`` of samples of ``y`` (1-D), evaluated at its centre; within
    half a window of the ends, of the polynomial through the first or last window."""
    half = window // 2
    position = np.arange(half, -half - 1, -1.0)  # reversed: a convolution
    powers = position ** np.arange(degree + 1)[:, None]
    unit = np.zeros(degree + 1)
    unit[deriv] = factorial(deriv) / delta**deriv
    weights = np.linalg.lstsq(powers, unit, rcond=np.finfo(float).eps * window)[0]
    out = np.convolve(y, weights, mode="same")
    for start, stop in ((0, half), (y.size - half, y.size)):
        edge = y[:window] if start == 0 else y[-window:]
        fit = np.polyder(np.polyfit(np.arange(window, dtype=float), edge, degree), deriv)
        at = np.arange(start, stop) - (0 if start == 0 else y.size - window)
        out[start:stop] = np.polyval(fit, at) / delta**deriv
    return out


def butterworth(order: int, cutoff: float) -> np.ndarray:
    """Second-order sections ``(b0, b1, b2, 1, a1, a2)`` of the digital Butterworth low-pass of even
    ``order`` at ``cutoff`` (a fraction of the Nyquist frequency): the analog prototype's poles,
    pre-warped and mapped by the bilinear transform, paired with their conjugates; sections ordered
    by their poles' distance from the unit circle, farthest first, the gain in the first."""
    if order % 2:
        raise ValueError(f"butterworth: the order must be even, got {order}")
    warped = 4.0 * np.tan(np.pi * cutoff / 2.0)
    analog = warped * -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))
    poles = (4.0 + analog) / (4.0 - analog)
    gain = warped**order * np.real(1.0 / np.prod(4.0 - analog))
    upper = poles[poles.imag > 0]
    upper = upper[np.argsort(-np.abs(1.0 - np.abs(upper)), kind="stable")]
    sos = np.array([[1.0, 2.0, 1.0, 1.0, -2.0 * p.real, (p * p.conjugate()).real] for p in upper])
    sos[0, :3] *= gain
    return sos


def zero_phase(sos: np.ndarray, x: np.ndarray, padlen: int | None = None) -> np.ndarray:
    """``x`` (1-D) filtered by the sections ``sos`` forwards and then backwards, on an odd extension
    of ``padlen`` samples at each end (default 3 times the filter's length), each pass started
    in the steady state of its first sample."""
    edge = 3 * (2 * len(sos) + 1) if padlen is None else padlen
    if x.size <= edge:
        raise ValueError(f"zero_phase: {x.size} samples do not exceed the padding of {edge}")
    ext = np.concatenate([2 * x[0] - x[edge:0:-1], x, 2 * x[-1] - x[-2:-edge - 2:-1]]) if edge else x
    steady = _steady_states(sos)
    y = _cascade(sos, ext, steady * ext[0])
    y = _cascade(sos, y[::-1], steady * y[-1])[::-1]
    return np.ascontiguousarray(y[edge:ext.size - edge] if edge else y)


def _steady_states(sos: np.ndarray) -> np.ndarray:
    """Each section's state (transposed direct form) in the steady state of a unit step at the
    cascade's input (``scipy.signal.sosfilt_zi``)."""
    states, scale = [], 1.0
    for b, a in zip(sos[:, :3], sos[:, 3:]):
        companion = np.array([[1.0 + a[1], -1.0], [a[2], 1.0]])  # I - A of the section's state update
        states.append(scale * np.linalg.solve(companion, b[1:] - a[1:] * b[0]))
        scale *= b.sum() / a.sum()
    return np.array(states)


def _cascade(sos: np.ndarray, x: np.ndarray, states: np.ndarray) -> np.ndarray:
    """``x`` through each section in turn from ``states``: ``y[n] + a1 y[n-1] + a2 y[n-2] = b0 x[n]
    + b1 x[n-1] + b2 x[n-2]``, the states entering the first two rows."""
    for (b, a), state in zip(zip(sos[:, :3], sos[:, 3:]), states):
        rhs = np.convolve(x, b)[:x.size]
        rhs[:2] += state[:min(2, x.size)]
        x = _recursion(float(a[1]), float(a[2]), rhs)
    return x


def _recursion(a1: float, a2: float, r: np.ndarray) -> np.ndarray:
    """``y[n] = r[n] - a1 y[n-1] - a2 y[n-2]`` from rest, sample by sample in plain floats (a fifth
    of a microsecond a sample; as accurate as scipy's C loop, where blocked matrix forms lose digits
    on poles near 1)."""
    out, y1, y2 = [], 0.0, 0.0
    append = out.append
    for value in r.tolist():
        y1, y2 = value - a1 * y1 - a2 * y2, y1
        append(y1)
    return np.array(out)
