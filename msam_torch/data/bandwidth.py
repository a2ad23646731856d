"""The band a record's signals occupy, and anti-aliased decimation of records sampled far faster
than it (docs/design.md section 3b: scales come from the system, not from the record).

The band edge of a signal is the frequency below which :data:`POWER_SHARE` of its power above the
white-noise floor lies. A record sampled more than ``2 * RESOLVED`` times per period of the highest
band edge among its measured signals (states, derivatives and inputs alike) is *oversampled*: it
is low-pass filtered and decimated to keep at least :data:`RESOLVED` samples per period, which
loses none of the band and averages the noise above it away. Records of up to 200 samples per
period (every bundled and generated one) are left as they are.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from msam_torch.data.derivatives import BAND, noise_level, periodogram
from msam_torch.data.filters import lowpass, resample

POWER_SHARE = 0.99  # share of a signal's power above the noise floor that lies in the band
RESOLVED = 100  # samples per period of the band edge an oversampled record keeps
TAPS_PER_FACTOR = 20  # anti-alias FIR length per unit of the decimation factor (scipy.signal.decimate's)


def band_edge(y: np.ndarray) -> float:
    """Frequency (cycles per sample) below which :data:`POWER_SHARE` of the power of ``y`` above
    its white-noise floor lies (detrended, Hann-tapered, band-averaged periodogram; scaled to unit
    peak first, so that no magnitude overflows)."""
    peak = np.abs(y).max()
    y = y / peak if 0 < peak < np.inf else y
    freq, power, floor = periodogram(y, noise_level(y))
    signal = np.clip(moving_average(power, min(BAND, power.size)) - floor, 0.0, None)
    total = np.cumsum(signal)
    if total[-1] <= 0:
        return 0.5
    return float(freq[np.searchsorted(total, POWER_SHARE * total[-1])])


def moving_average(y: np.ndarray, size: int) -> np.ndarray:
    """The mean of the ``size`` samples around each sample of ``y`` (the edge samples repeated
    beyond the ends; ``scipy.ndimage.uniform_filter1d(mode='nearest')``)."""
    padded = np.pad(y, (size // 2, (size - 1) // 2), mode="edge")
    return np.convolve(padded, np.full(size, 1.0 / size), mode="valid")


def decimate(values: np.ndarray, every: int) -> np.ndarray:
    """Every ``every``-th sample of ``values`` after a zero-phase FIR low-pass at the new Nyquist
    frequency (the filter of ``scipy.signal.decimate``); the ends are extended along the line through
    the first and last samples (:func:`~msam_torch.data.filters.resample`), so they keep their level."""
    if every == 1:
        return values
    return resample(values, 1, every, lowpass(TAPS_PER_FACTOR * every + 1, 1.0 / every))


def oversampling(signals: Mapping[str, np.ndarray]) -> tuple[int, float]:
    """The decimation factor of a uniformly sampled record (1: not oversampled) and the highest
    band edge (cycles per sample) among its non-constant ``signals``."""
    edges = [band_edge(v) for v in signals.values() if v.size > 2 * BAND and np.ptp(v) > 0]
    band = max(edges, default=0.5)
    return max(1, int(1.0 / (RESOLVED * band))), band
