"""The record filters (msam_torch.data.filters) agree with the scipy.signal routines they stand for,
to rounding, on random walks with a trend: the FIR low-pass, resampling with line-extended ends
(down and up, 1-D and rows), Savitzky-Golay with fitted ends, the Butterworth sections and their
zero-phase application; and the band's moving average with scipy.ndimage's."""
import numpy as np
import pytest
import scipy.signal as sig
from scipy.ndimage import uniform_filter1d

from msam_torch.data import filters
from msam_torch.data.bandwidth import moving_average

RNG = np.random.default_rng(0)
SIGNALS = {n: np.cumsum(RNG.standard_normal(n)) + np.linspace(0.0, 5.0, n) for n in (40, 1001)}


def close(found, expected, rtol=1e-12):
    assert found.shape == expected.shape
    np.testing.assert_allclose(found, expected, rtol=0, atol=rtol * np.abs(expected).max())


@pytest.mark.parametrize("every", [2, 3, 7])
def test_lowpass_and_decimation_match_firwin_and_resample_poly(every):
    taps = filters.lowpass(20 * every + 1, 1.0 / every)
    close(taps, sig.firwin(20 * every + 1, 1.0 / every, window="hamming"))
    for x in SIGNALS.values():
        close(filters.resample(x, 1, every, taps), sig.resample_poly(x, 1, every, window=taps, padtype="line"))


@pytest.mark.parametrize("up", [2, 5])
def test_upsampling_matches_resample_poly_on_rows(up):
    for x in SIGNALS.values():
        rows = np.stack([x, -2.0 * x[::-1]])
        close(filters.resample(rows, up, 1), sig.resample_poly(rows, up, 1, axis=-1, padtype="line"))


@pytest.mark.parametrize("window, deriv", [(5, 0), (15, 1), (31, 2), (7, 3)])
def test_savgol_matches_savgol_filter_with_fitted_ends(window, deriv):
    for x in SIGNALS.values():
        expected = sig.savgol_filter(x, window, 3, deriv=deriv, delta=0.01, mode="interp")
        close(filters.savgol(x, window, 3, deriv, 0.01), expected, rtol=1e-11)


@pytest.mark.parametrize("cutoff", [0.02, 0.3, 0.8])
def test_butterworth_sections_and_zero_phase_match_butter_and_sosfiltfilt(cutoff):
    sos = filters.butterworth(4, cutoff)
    close(sos, sig.butter(4, cutoff, output="sos"))
    for x in SIGNALS.values():
        for padlen in (None, x.size - 1):
            close(filters.zero_phase(sos, x, padlen), sig.sosfiltfilt(sos, x, padlen=padlen), rtol=1e-11)
    with pytest.raises(ValueError, match="even"):
        filters.butterworth(3, cutoff)
    with pytest.raises(ValueError, match="padding"):
        filters.zero_phase(sos, np.ones(10))


@pytest.mark.parametrize("size", [1, 2, 8, 31])
def test_moving_average_matches_uniform_filter1d(size):
    y = RNG.random(200) * 10 ** RNG.uniform(-3, 3, 200)
    close(moving_average(y, size), uniform_filter1d(y, size=size, mode="nearest"))
