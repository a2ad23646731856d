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
from scipy.ndimage import uniform_filter1d
from scipy.signal import firwin, resample_poly

from msam_torch.data.derivatives import BAND, noise_level, periodogram

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
    signal = np.clip(uniform_filter1d(power, size=min(BAND, power.size), mode="nearest") - floor, 0.0, None)
    total = np.cumsum(signal)
    if total[-1] <= 0:
        return 0.5
    return float(freq[np.searchsorted(total, POWER_SHARE * total[-1])])


def decimate(values: np.ndarray, every: int) -> np.ndarray:
    """Every ``every``-th sample of ``values`` after a zero-phase FIR low-pass at the new Nyquist
    frequency (the filter of ``scipy.signal.decimate``); the ends are extended along a fitted line
    (``resample_poly(padtype='line')``), so the first and last samples keep their level."""
    if every == 1:
        return values
    taps = firwin(TAPS_PER_FACTOR * every + 1, 1.0 / every, window="hamming")
    return resample_poly(values, 1, every, window=taps, padtype="line")


def oversampling(signals: Mapping[str, np.ndarray]) -> tuple[int, float]:
    """The decimation factor of a uniformly sampled record (1: not oversampled) and the highest
    band edge (cycles per sample) among its non-constant ``signals``."""
    edges = [band_edge(v) for v in signals.values() if v.size > 2 * BAND and np.ptp(v) > 0]
    band = max(edges, default=0.5)
    return max(1, int(1.0 / (RESOLVED * band))), band
