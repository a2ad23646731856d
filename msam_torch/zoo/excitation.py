"""Random excitation signals on a dense time grid, scaled to ``[-1, 1]``: random-phase multisines
whose band reaches 0.01-0.2 of the sampling rate, random step sequences, and PRBS
(``scipy.signal.max_len_seq``) held for as many samples as its band asks. Steps and PRBS switch
only at the sampling instants and hold their value until the next (zero-order hold), as a
digital-to-analog converter clocked with the acquisition applies them: a switch between two
samples would leave its instant unrecorded, an input no record can tell the method.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

KINDS = ("multisine", "steps", "prbs")


def multisine(rng: np.random.Generator, t: np.ndarray, band: float) -> np.ndarray:
    """Sum of equal-amplitude sines at the record's harmonics up to ``band`` (cycles per time unit)."""
    duration = t[-1] - t[0]
    harmonics = np.arange(1, max(2, int(band * duration)) + 1) / duration
    phases = rng.uniform(0, 2 * np.pi, harmonics.size)
    return np.sin(2 * np.pi * np.outer(t - t[0], harmonics) + phases).sum(-1)


def steps(rng: np.random.Generator, t: np.ndarray, band: float) -> np.ndarray:
    """Random levels held for random times of about ``1 / band`` to ``5 / band``."""
    out = np.empty_like(t)
    k = 0
    while k < t.size:
        hold = rng.uniform(1.0, 5.0) / band
        n = max(1, int(np.searchsorted(t, t[k] + hold) - k))
        out[k:k + n] = rng.uniform(-1, 1)
        k += n
    return out


def prbs(rng: np.random.Generator, t: np.ndarray, band: float) -> np.ndarray:
    """A maximum-length binary sequence with bit time ``1 / (2 band)``, random start in the sequence."""
    bit = 1 / (2 * band)
    bits = int(np.ceil((t[-1] - t[0]) / bit)) + 1
    nbits = max(4, int(np.ceil(np.log2(bits + 1))))
    sequence = signal.max_len_seq(nbits, state=rng.integers(0, 2, nbits) | (np.arange(nbits) == 0))[0]
    index = ((t - t[0]) / bit).astype(int) % sequence.size
    return 2.0 * sequence[index] - 1.0


def draw(rng: np.random.Generator, t: np.ndarray, sample_rate: float, kind: str | None = None,
         fraction: float | None = None) -> tuple[np.ndarray, dict]:
    """A random excitation on grid ``t`` (max |e| = 1) and its description; ``fraction``: its band
    as a share of the sampling rate (default drawn)."""
    kind = kind or str(rng.choice(KINDS))
    fraction = fraction or float(np.exp(rng.uniform(np.log(0.01), np.log(0.2))))
    held = t if kind == "multisine" else t[0] + np.floor((t - t[0]) * sample_rate + 1e-6) / sample_rate
    e = {"multisine": multisine, "steps": steps, "prbs": prbs}[kind](rng, held, fraction * sample_rate)
    e = e - (0.0 if kind == "prbs" else e.mean())
    return e / np.abs(e).max(), {"kind": kind, "band_fraction_of_sample_rate": fraction}
