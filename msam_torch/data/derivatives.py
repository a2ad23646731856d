"""State and derivative estimation from sampled signals, with well-kept library code.

A derivative estimator is any object with a ``name`` and ``estimate(t, y, order, where)``
(:class:`DerivativeEstimator`); ``data.derivatives`` names one of :data:`ESTIMATORS` or, from
Python, is one (``SavitzkyGolay(window=15)``). ``data.window`` and ``data.cutoff`` set the estimator's
``window`` and ``cutoff`` fields where it has them (:func:`configured`). Besides the estimators below,
``exact`` (:class:`Exact`: every signal the model reads is given) and ``auto`` (:class:`Auto`: exact
for a noise-free simulated system, else ``savgol``) are registered.

Estimators (all return the smoothed signal and its first ``order`` derivatives):
- ``savgol``: Savitzky-Golay, local cubic (``scipy.signal.savgol_filter``'s, :mod:`~msam_torch.data.filters`), the default;
- ``spline``: penalised cubic smoothing spline, penalty by generalised cross-validation
  (``scipy.interpolate.make_smoothing_spline``);
- ``loess``: locally weighted linear regression (statsmodels ``lowess``, the paper's choice), then
  a cubic interpolating spline for the derivatives;
- ``finite_difference``: no smoothing, second-order central differences (``numpy.gradient``);
- ``butterworth``: zero-phase low-pass Butterworth filter of order 4 run forwards and backwards
  (``scipy.signal.butter`` + ``sosfiltfilt``'s, :mod:`~msam_torch.data.filters`), then second-order central differences of the filtered
  signal: the filtering chain of inverse-dynamics identification (IDIM-LS) of mechanical systems.
  The cut-off is ``data.cutoff`` (cycles per time unit, Hz for seconds) or the noise-floor rule below.
- ``interpolating_spline``: no smoothing, a quintic interpolating spline
  (``scipy.interpolate.make_interp_spline``), for low-noise records sampled near their bandwidth.

Local polynomials (``savgol``, ``finite_difference``, ``loess``) differentiate accurately only well
below the Nyquist frequency: nested central differences lose 43 % of a second derivative at 0.2
cycles per sample and 83 % at 1/3 (a record whose input reaches a third of the sampling rate).
An interpolating spline of odd degree tends to the band-limited (sinc) reconstruction as its degree
grows; the quintic one keeps the error of both derivatives under 0.5 % up to 0.2 and near 5 % at 1/3
cycles per sample. It does not smooth, so its noise grows like ``omega^k`` up to the Nyquist frequency.

Window rule (``savgol`` and ``loess`` when no window is given): the smoother should pass what
the record holds above its noise and stop where the noise takes over, the cut-off of a Wiener
filter. :func:`cutoff_frequency` finds the lowest frequency above the spectrum's peak at which the
signal's power (tapered periodogram, averaged over the octave around each frequency) falls to the
white-noise power set by :func:`noise_level` (``butterworth`` takes that frequency as its cut-off),
and :func:`choose_window` picks the window whose cut-off frequency is there (Schafer 2011:
``f_c ~ (p + 1) / (3.2 w - 4.6)`` cycles per sample for a local polynomial of degree ``p``).
The average spans a fixed ratio of frequencies, not a fixed number of bins, so the rule does not
depend on the record's length: a longer record has finer bins, and a few bins' average would fall to
the floor in the gaps between a multisine's lines (or below its lowest line), cutting the band off
at its first line. An octave bridges the gaps of a band's lines and ends up to half an octave past
its last line. Differentiation multiplies signal and noise alike by ``omega^k``, so the same cut-off
serves every derivative order. Noise-free records get the smallest windows; noisier records get
wider ones.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from math import comb
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from msam_torch.config.registry import Registry
from msam_torch.data.filters import butterworth, savgol, zero_phase
from msam_torch.errors import DataError

SAVGOL_DEGREE = 3  # local cubic: unbiased for the first two derivatives of a cubic
LOESS_DEGREE = 1  # statsmodels lowess fits local lines
BUTTERWORTH_ORDER = 4  # as in inverse-dynamics identification of robots and drives (IDIM-LS)
HIGHEST_CUTOFF = 0.45  # cycles per sample: a low-pass cut-off must lie below Nyquist (0.5)
INTERPOLATING_DEGREE = 5  # odd: the quintic interpolating spline
OCTAVE = 2**0.5  # the periodogram is averaged over [f / OCTAVE, f * OCTAVE] before the noise floor is met
BAND = 9  # and over this many bins at least
DIFFERENCE_ORDERS = range(3, 9)  # the noise level is read from the differences of these orders


@dataclass(frozen=True)
class Estimate:
    """``values[k]`` is the k-th derivative (k = 0 is the smoothed signal); ``info`` says how."""

    values: list[np.ndarray]
    info: dict


def noise_level(y: np.ndarray) -> float:
    """Rough standard deviation of white measurement noise from the signal's differences.

    The ``k``-th difference of white noise has variance ``C(2k, k) sigma^2`` at every ``k``; that of
    a smooth signal shrinks with ``k`` where its power lies below about a sixth of the sampling
    rate, and the median ignores kinks at a minority of the samples (a state driven by a held
    input that switches every few samples): the least of the estimates over
    :data:`DIFFERENCE_ORDERS`, each the median absolute deviation of the differences over
    ``sqrt(C(2k, k))``. A signal with most of its power near the Nyquist frequency (a state that
    relaxes within a sample, switched every sample or two) still reads as noise at every order."""
    y = np.asarray(y, dtype=float)
    levels = []
    for k in (k for k in DIFFERENCE_ORDERS if y.size >= k + 2):
        d = np.diff(y, k)
        levels.append(np.median(np.abs(d - np.median(d))) * 1.4826 / np.sqrt(comb(2 * k, k)))
    return float(min(levels, default=float("nan")))


def periodogram(y: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Frequencies (cycles per sample), the periodogram of the linearly detrended, Hann-tapered ``y``,
    and the floor white noise of std ``sigma`` gives it in every bin (``sigma^2 sum(taper^2)``)."""
    n = y.size
    index = np.arange(n)
    detrended = y - np.polyval(np.polyfit(index, y, 1), index)
    taper = np.hanning(n)
    return np.fft.rfftfreq(n), np.abs(np.fft.rfft(detrended * taper)) ** 2, sigma**2 * float(np.sum(taper**2))


def cutoff_frequency(y: np.ndarray, sigma: float) -> float:
    """Lowest frequency (cycles per sample) above the peak of the averaged periodogram where the
    periodogram of ``y``, averaged over ``[f / OCTAVE, f * OCTAVE]`` (and :data:`BAND` bins at
    least), falls to twice the floor of white noise of std ``sigma``: there the signal's power no
    longer exceeds the noise's (the Wiener gain falls to 1/2)."""
    freq, power, floor = periodogram(y, sigma)
    k = np.arange(power.size)
    low = np.maximum(np.minimum(np.floor(k / OCTAVE).astype(int), k - BAND // 2), 0)
    high = np.minimum(np.maximum(np.ceil(k * OCTAVE).astype(int), k + BAND // 2), power.size - 1)
    tail = np.append(np.cumsum(power[::-1])[::-1], 0.0)  # sums from the top, where the power is small: exact there
    band = (tail[low] - tail[high + 1]) / (high + 1 - low)
    peak = int(np.argmax(band))
    below = np.flatnonzero(band[peak:] <= 2.0 * floor)  # signal power <= noise power
    return float(freq[peak + below[0]] if below.size else freq[-1])


def choose_window(y: np.ndarray, degree: int) -> tuple[int, float]:
    """Odd window (samples) of a degree-``degree`` local fit whose cut-off matches the noise floor;
    returns the window and the cut-off in cycles per sample."""
    n = y.size
    cutoff = max(cutoff_frequency(y, noise_level(y)), 1.0 / n)
    smallest = (degree + 2) | 1
    largest = n if n % 2 else n - 1
    return max(smallest, min(window_for(degree, cutoff), largest)), cutoff


def window_for(degree: int, cutoff: float) -> int:
    """Odd window of a degree-``degree`` local fit with cut-off ``cutoff`` cycles per sample (Schafer 2011)."""
    return int(round(((degree + 1) / cutoff + 4.6) / 3.2)) | 1


@dataclass(frozen=True)
class InBand:
    """``inner`` with its noise-floor cut-off raised to at least ``band`` cycles per sample, so it
    does not cut into the band the record's inputs excite (a window or cut-off given is kept)."""

    inner: "DerivativeEstimator"
    band: float

    @property
    def name(self) -> str:
        return self.inner.name

    def estimate(self, t, y, order, where="signal") -> Estimate:
        chosen, rule = self.inner.choose(False) if isinstance(self.inner, Auto) else self.inner, None
        if takes(chosen, "window") and chosen.window is None:
            degree = LOESS_DEGREE if isinstance(chosen, Loess) else max(SAVGOL_DEGREE, order)
            window = choose_window(np.asarray(y, dtype=float), degree)[0]
            chosen = dataclasses.replace(chosen, window=min(window, max(window_for(degree, self.band), degree + 2)))
            rule = f"noise floor, at most the window that passes the band ({self.band:.4g} cycles/sample)"
        elif takes(chosen, "cutoff") and chosen.cutoff is None:
            dt = float(np.median(np.diff(t)))
            noise_floor = cutoff_frequency(np.asarray(y, dtype=float), noise_level(y))
            chosen = dataclasses.replace(chosen, cutoff=min(max(noise_floor, self.band), HIGHEST_CUTOFF) / dt)
            rule = f"noise floor, at least the band ({self.band:.4g} cycles/sample)"
        out = chosen.estimate(t, y, order, where)
        return out if rule is None else Estimate(out.values, {**out.info, "window_rule": rule})


@runtime_checkable
class DerivativeEstimator(Protocol):
    """Smooths a sampled signal ``y(t)`` and estimates its first ``order`` derivatives; ``where``
    names the signal in errors (a file and column)."""

    name: str

    def estimate(self, t: np.ndarray, y: np.ndarray, order: int, where: str = "signal") -> Estimate: ...


class Smoother:
    """The checks every built-in estimator shares: a constant signal has no derivatives, the
    libraries' numeric failures become :class:`DataError` naming the signal, estimates are finite.
    ``info`` records the method, the window (samples, ``None`` where not windowed) or cut-off, how it
    was chosen, the local degree or filter order and the noise estimate, for the result's provenance."""

    name: ClassVar[str]

    def estimate(self, t: np.ndarray, y: np.ndarray, order: int, where: str = "signal") -> Estimate:
        try:
            with np.errstate(all="ignore"):
                t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
                if order > 0 and y.size > 1 and np.ptp(y) == 0:
                    raise DataError(f"{where}: the signal is constant, so its derivatives carry no information")
                info = {"method": self.name, "window": None, "window_rule": None, "noise_std": noise_level(y)}
                result = self._estimate(t, y, order, where, info)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # the libraries' numeric failures
            raise DataError(f"{where}: the {self.name} estimator failed: "
                            f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
        if not all(np.isfinite(v).all() for v in result.values):
            raise DataError(f"{where}: the {self.name} estimates are not finite (values too large or too close in time?)")
        return result

    def _estimate(self, t: np.ndarray, y: np.ndarray, order: int, where: str, info: dict) -> Estimate:
        raise NotImplementedError


def _differences(t: np.ndarray, y: np.ndarray, order: int) -> list[np.ndarray]:
    """``y`` and its nested second-order central differences up to ``order``."""
    values = [y]
    for _ in range(order):
        values.append(np.gradient(values[-1], t, edge_order=2))
    return values


def _enough_for_differences(y: np.ndarray, order: int, where: str) -> None:
    if y.size < order + 2:
        raise DataError(f"{where}: {y.size} samples are too few for finite differences of order {order} "
                        f"(need {order + 2})")


@dataclass(frozen=True)
class FiniteDifference(Smoother):
    """No smoothing: second-order central differences (``numpy.gradient``)."""

    name: ClassVar[str] = "finite_difference"

    def _estimate(self, t, y, order, where, info):
        _enough_for_differences(y, order, where)
        return Estimate(_differences(t, y, order), info)


@dataclass(frozen=True)
class Butterworth(Smoother):
    """Zero-phase Butterworth low-pass at ``cutoff`` (cycles per time unit; ``None``: the noise
    floor), then central differences of the filtered signal."""

    name: ClassVar[str] = "butterworth"
    cutoff: float | None = None

    def _estimate(self, t, y, order, where, info):
        _enough_for_differences(y, order, where)
        y, info = _butterworth(t, y, self.cutoff, where, info)
        return Estimate(_differences(t, y, order), info)


@dataclass(frozen=True)
class InterpolatingSpline(Smoother):
    """No smoothing: the quintic interpolating spline (``scipy.interpolate.make_interp_spline``)."""

    name: ClassVar[str] = "interpolating_spline"

    def _estimate(self, t, y, order, where, info):
        from scipy.interpolate import make_interp_spline

        degree = max(INTERPOLATING_DEGREE, order + 2) | 1
        if y.size < degree + 1:
            raise DataError(f"{where}: {y.size} samples are too few for an interpolating spline of degree {degree} "
                            f"(need {degree + 1})")
        spline = make_interp_spline(t, y, k=degree)
        return Estimate([y] + [spline(t, nu=k) for k in range(1, order + 1)], {**info, "degree": degree})


@dataclass(frozen=True)
class SmoothingSpline(Smoother):
    """Penalised cubic smoothing spline, penalty by generalised cross-validation."""

    name: ClassVar[str] = "spline"

    def _estimate(self, t, y, order, where, info):
        from scipy.interpolate import make_smoothing_spline

        if y.size < 5:
            raise DataError(f"{where}: {y.size} samples are too few for a smoothing spline (need 5)")
        spline = make_smoothing_spline(t, y)
        return Estimate([spline(t, nu=k) for k in range(order + 1)], {**info, "window_rule": "gcv", "degree": 3})


def _local_window(method: str, y: np.ndarray, degree: int, window: int | None, where: str, info: dict,
                  odd: bool) -> tuple[int, dict]:
    """The window of a local fit of ``degree``: given, or by the noise-floor rule (:func:`choose_window`)."""
    n = y.size
    smallest = (degree + 2) | 1
    if n < smallest:
        raise DataError(f"{where}: {n} samples are fewer than the smallest {method} window of {smallest} samples")
    rule = "given"
    if window is None:
        window, cutoff = choose_window(y, degree)
        rule = f"noise floor (cut-off {cutoff:.4g} cycles/sample)"
    if odd and window % 2 == 0:
        window += 1
    if window > n or window < smallest:
        raise DataError(f"{where}: {n} samples do not fit the derivative window of {window} samples "
                        f"(data.window must lie between {smallest} and {n})")
    return window, {**info, "window": int(window), "window_rule": rule, "degree": degree}


@dataclass(frozen=True)
class SavitzkyGolay(Smoother):
    """Savitzky-Golay local cubic of ``window`` samples (``None``: the noise-floor rule)."""

    name: ClassVar[str] = "savgol"
    window: int | None = None

    def _estimate(self, t, y, order, where, info):
        degree = max(SAVGOL_DEGREE, order)
        window, info = _local_window(self.name, y, degree, self.window, where, info, odd=True)
        dt = float(np.median(np.diff(t)))
        return Estimate([savgol(y, window, degree, k, dt) for k in range(order + 1)], info)


@dataclass(frozen=True)
class Loess(Smoother):
    """Locally weighted linear regression (statsmodels ``lowess``) of ``window`` samples, then a
    cubic interpolating spline for the derivatives."""

    name: ClassVar[str] = "loess"
    window: int | None = None

    def _estimate(self, t, y, order, where, info):
        from scipy.interpolate import CubicSpline
        from statsmodels.nonparametric.smoothers_lowess import lowess

        window, info = _local_window(self.name, y, LOESS_DEGREE, self.window, where, info, odd=False)
        smooth = lowess(y, t, frac=min(1.0, window / y.size), it=0, return_sorted=False)
        spline = CubicSpline(t, smooth)
        return Estimate([smooth] + [spline(t, nu=k) for k in range(1, order + 1)], info)


@dataclass(frozen=True)
class Exact:
    """``exact``: every signal the model reads is given (measured, or simulated without noise);
    nothing is estimated."""

    name: ClassVar[str] = "exact"

    def estimate(self, t, y, order, where="signal") -> Estimate:
        raise DataError(f"{where}: data.derivatives is 'exact', so derivatives are not estimated; "
                        f"choose an estimator ({', '.join(METHODS)})")


@dataclass(frozen=True)
class Auto:
    """``auto``: :class:`Exact` for a noise-free simulated system, else :class:`SavitzkyGolay`."""

    name: ClassVar[str] = "auto"
    window: int | None = None

    def choose(self, noise_free_simulation: bool) -> DerivativeEstimator:
        return Exact() if noise_free_simulation else SavitzkyGolay(self.window)

    def estimate(self, t, y, order, where="signal") -> Estimate:
        """Estimates from measurements, where nothing is exact: Savitzky-Golay's."""
        return self.choose(False).estimate(t, y, order, where)


SMOOTHERS = (SavitzkyGolay, SmoothingSpline, Loess, FiniteDifference, Butterworth, InterpolatingSpline)
METHODS = tuple(s.name for s in SMOOTHERS)  # the estimators proper
ESTIMATORS: Registry[DerivativeEstimator] = Registry("data.derivatives", DerivativeEstimator, "derivative estimator")
for _estimator in (Auto, Exact, *SMOOTHERS):
    ESTIMATORS.register(_estimator.name, _estimator)


def configured(estimator: DerivativeEstimator, window: int | None = None,
               cutoff: float | None = None) -> DerivativeEstimator:
    """``estimator`` with ``data.window`` / ``data.cutoff`` set where it has that field; a setting
    it has no field for is left out (see :func:`takes`)."""
    given = {k: v for k, v in (("window", window), ("cutoff", cutoff)) if v is not None and takes(estimator, k)}
    return dataclasses.replace(estimator, **given) if given else estimator


def takes(estimator: DerivativeEstimator, setting: str) -> bool:
    """Whether ``estimator`` has the dataclass field ``setting`` (``window``, ``cutoff``)."""
    return dataclasses.is_dataclass(estimator) and setting in {f.name for f in dataclasses.fields(estimator)}


def estimate(t: np.ndarray, y: np.ndarray, order: int, method: str | DerivativeEstimator = "savgol",
             window: int | None = None, name: str = "signal", cutoff: float | None = None) -> Estimate:
    """Smooth ``y(t)`` and estimate derivatives up to ``order`` with ``method`` (a registered name
    or an estimator) and its ``window`` or ``cutoff``; errors name ``name``."""
    return configured(ESTIMATORS.resolve(method), window, cutoff).estimate(t, y, order, name)


def _butterworth(t: np.ndarray, y: np.ndarray, cutoff: float | None, name: str, info: dict) -> tuple[np.ndarray, dict]:
    """Zero-phase Butterworth low-pass of ``y`` at ``cutoff`` (cycles per time unit; default the
    noise-floor frequency of :func:`cutoff_frequency`)."""
    dt = float(np.median(np.diff(t)))
    rule = "given"
    if cutoff is None:
        per_sample = min(max(cutoff_frequency(y, noise_level(y)), 1.0 / y.size), HIGHEST_CUTOFF)
        rule = "noise floor"
    else:
        per_sample = cutoff * dt
        if not 0 < per_sample < 0.5:
            raise DataError(f"{name}: data.cutoff={cutoff:g} must lie between 0 and the Nyquist frequency "
                            f"{0.5 / dt:.6g} (cycles per time unit)")
    sos = butterworth(BUTTERWORTH_ORDER, 2.0 * per_sample)
    # odd extension over ~3 periods at the cut-off, never shorter than scipy's default (27 samples for
    # this order), which alone leaves the start-up transient of a low cut-off in the edge derivatives
    padding = min(max(int(np.ceil(3.0 / per_sample)), 3 * (2 * len(sos) + 1)), y.size - 1)
    info = {**info, "cutoff": per_sample / dt, "cutoff_per_sample": per_sample, "window_rule": rule,
            "filter_order": BUTTERWORTH_ORDER, "zero_phase": True}
    return zero_phase(sos, y, padding), info
