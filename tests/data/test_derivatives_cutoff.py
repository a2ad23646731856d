"""The noise-floor cut-off of the derivative smoothers (msam_torch.data.derivatives.cutoff_frequency)
does not depend on the record length: a multisine recorded 1x and 20x longer at the same sampling
period gets the same cut-off, above its highest line."""
import numpy as np
import pytest

from msam_torch.data.derivatives import Butterworth, InBand, SavitzkyGolay, cutoff_frequency, estimate, noise_level

LINES = (0.004, 0.007, 0.011, 0.015, 0.019, 0.024)  # cycles per sample: a band with gaps between lines
NOISE = 0.01  # of the signal's standard deviation


def multisine(samples: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A multisine of :data:`LINES` (Schroeder phases, unit amplitudes) and its white-noise record."""
    n = np.arange(samples)
    k = len(LINES)
    clean = sum(np.sin(2 * np.pi * f * n - np.pi * i * (i - 1) / k) for i, f in enumerate(LINES, 1))
    return clean, clean + NOISE * clean.std() * np.random.default_rng(seed).standard_normal(samples)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cutoff_of_a_multisine_does_not_depend_on_the_record_length(seed):
    cutoffs = []
    for samples in (2000, 40000):
        _, y = multisine(samples, seed)
        cutoffs.append(cutoff_frequency(y, noise_level(y)))
    assert all(c > max(LINES) for c in cutoffs), cutoffs
    assert cutoffs[1] == pytest.approx(cutoffs[0], rel=0.3), cutoffs


def derivative_errors(samples: int, seed: int) -> np.ndarray:
    """RMS errors (relative, away from the ends) of the smoothed multisine and its first two
    derivatives with the noise-floor Savitzky-Golay window."""
    clean, y = multisine(samples, seed)
    n = np.arange(samples, dtype=float)
    w = 2 * np.pi * np.asarray(LINES)
    phases = [-np.pi * i * (i - 1) / len(LINES) for i in range(1, len(LINES) + 1)]
    exact = [clean, sum(wi * np.cos(wi * n + p) for wi, p in zip(w, phases)),
             sum(-wi**2 * np.sin(wi * n + p) for wi, p in zip(w, phases))]
    values = estimate(n, y, 2, "savgol").values
    inner = slice(200, -200)
    return np.array([np.sqrt(np.mean((v[inner] - e[inner]) ** 2) / np.mean(e[inner] ** 2)) for v, e in zip(values, exact)])


def test_long_record_estimates_derivatives_as_well_as_a_short_one():
    """20x the record, same sampling period: the window and so the errors of the signal and its
    derivatives stay within 25 % of the short record's (a window grown with the record smooths the
    band away: errors near 100 %)."""
    short, long = derivative_errors(2000, 0), derivative_errors(40000, 0)
    assert long == pytest.approx(short, rel=0.25), (short, long)
    assert long[0] < 0.1 and long[2] < 0.5, long


def test_cutoff_of_white_noise_and_of_a_noise_free_record():
    """Nothing above the floor: no frequency is worth its noise; no noise: every frequency is."""
    y = np.random.default_rng(4).standard_normal(5000)
    assert cutoff_frequency(y, noise_level(y)) < 0.05
    clean, _ = multisine(2000, 0)
    assert cutoff_frequency(clean, 0.0) == 0.5


@pytest.mark.parametrize("inner, rule", [("savgol", "noise floor, at most the window"), ("butterworth", "noise floor, at least"),
                                         ("savgol(window=15)", "given")])
def test_the_band_kept_estimator_says_how_its_window_was_chosen(inner, rule):
    """The weak form's estimator (:class:`~msam_torch.data.derivatives.InBand`) chooses a window or cut-off
    the user did not give; the record's provenance says so (before: ``given``)."""
    estimator = {"savgol": SavitzkyGolay(), "butterworth": Butterworth(), "savgol(window=15)": SavitzkyGolay(window=15)}[inner]
    _, y = multisine(2000, 0)
    info = InBand(estimator, 0.03).estimate(np.arange(y.size, dtype=float), y, 1, "y").info
    assert info["window_rule"].startswith(rule), info
