"""Estimation chosen from the record (docs/design.md section 3b): the band the signals occupy, the
test-function half-width and quadrature rate it implies, and the weak form's signals (for the
diagnosis, and for ``adapt`` in the weak form, ``adaptation.form``).

The weak form integrates the measured signals themselves; a derivative the data do not hold
(``x_dot`` with only ``x`` measured) is estimated with a smoother whose cut-off lies above the
band (:class:`~msam_torch.data.derivatives.InBand`). The band edge ``f_b`` is the highest, over the
measured states (what the inputs excited in the system; :func:`record_band`, the diagnosis's rule)
or over the signals the regressors read (:func:`regressor_band`, ``adapt``'s), of the frequency
below which 99 % of a signal's power above its white-noise floor lies; the bump test function
passes ``f_b`` at half amplitude for the half-width ``h = 0.6 / f_b`` (time units of the system,
not a share of the record). Records sampled far faster than the band are low-pass filtered and
decimated (:func:`~msam_torch.data.bandwidth.decimate`) to about :data:`SAMPLES` samples, never below 7
samples per band period nor 16 per half-width. A record sampled so slowly that a half-width holds
fewer than 16 samples is, for the diagnosis, interpolated between them (:func:`refined`), to at most
16 times :data:`SAMPLES` samples."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import torch

from msam_torch.config.schema import DataConfig
from msam_torch.data import hold
from msam_torch.data.bandwidth import band_edge, decimate
from msam_torch.data.derivatives import DerivativeEstimator, InBand
from msam_torch.data.filters import resample
from msam_torch.data.loading import Dataset, build_dataset
from msam_torch.engine.weak_form import TestFunctions, half_width_for, weak_data
from msam_torch.errors import DataError, MSAMError
from msam_torch.model.spec import ModelSpec, derivative_name, split_derivative
from msam_torch.simulation.equations import EquationModel

SAMPLES_PER_PERIOD = 7  # decimation keeps the band edge below 1/7 of the sampling rate
DERIVATIVE_MARGIN = 2.0  # a derivative's smoother passes twice the band edge
QUADRATURE = 16  # decimation keeps at least this many samples in a half-width
REFINE = 8  # a record with fewer samples in a half-width is interpolated at most this many-fold
SAMPLES = 1000  # records are low-pass filtered and decimated to about this many samples


def record_band(measured: Mapping[str, np.ndarray], inputs) -> tuple[float, dict]:
    """The band edge (cycles per sample, :func:`~msam_torch.data.bandwidth.band_edge`) of a record: the
    highest over its varying measured states, what the inputs excited in the system (over the
    inputs too when no state varies); and each varying signal's."""
    edges = {k: band_edge(v) for k, v in measured.items() if k != "t" and np.ptp(v) > 0}
    states = [edge for k, edge in edges.items() if k not in inputs]
    return max(states or edges.values(), default=0.5), edges


def regressor_band(spec: ModelSpec, dataset: Dataset) -> tuple[float, dict]:
    """The band edge (cycles per sample) of the signals the equations' regressors read: the
    highest over the states and their derivatives as estimated in ``dataset`` (neither inputs nor
    targets), so that test functions pass where the adjustment functions vary (a velocity's
    reversals, not only the position's slow swing); and each one's."""
    targets = {equation.target for equation in spec.equations}
    read = {k: v.detach().cpu().numpy() for k, v in dataset.signals.items() if k not in targets | set(spec.inputs)}
    return record_band(read, ())


@dataclass(frozen=True)
class Estimation:
    """The weak form's signals (training and held out), its test-function half-width (time units)
    and how both were chosen (``info``, the report's estimator section)."""

    train: dict
    held_out: dict | None
    half_width: float
    decimation: int
    info: dict
    refinement: int = 1  # the signals are interpolated this many-fold between the (decimated) samples

    @property
    def reach(self) -> int:
        """Samples of the weak form's grid over which a derivative estimate spreads one sample's
        noise (its widest window)."""
        derivatives = self.info["derivatives"]
        windows = [d.get("window") or 0 for d in derivatives.values()] if isinstance(derivatives, dict) else []
        return max(windows, default=0) * self.refinement

    def held_inputs(self, label: str) -> tuple[str, ...]:
        """The inputs the record ``label`` ('train' or 'held_out') holds between samples."""
        holds = self.info.get("input_hold" if label == "train" else "held_out_input_hold", {})
        return tuple(u for u, how in holds.items() if how == "zoh")

    def noise(self, levels: Mapping[str, float], trials: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """``trials`` draws (T, N) of white measurement noise of each signal's ``levels`` (standard
        deviation per recorded sample) as the training signals carry it: about ``1 / decimation``
        of its power kept by the anti-alias filter, interpolated between the samples as they are."""
        t = self.train["t"]
        n = (t.shape[-1] - 1) // self.refinement + 1
        draws = lambda level: torch.randn(trials, n, generator=generator, dtype=t.dtype) * level / self.decimation**0.5
        shape = _between(_held(self.info), self.decimation > 1)
        return {name: refined(draws(level).to(t.device), self.refinement, shape) for name, level in levels.items()}


def _measured(dataset: Dataset) -> dict[str, np.ndarray]:
    given = {"t": dataset.t, **(dataset.measured or dataset.signals)}
    return {k: v.detach().cpu().numpy() for k, v in given.items()}


@dataclass(frozen=True)
class Kink:
    """The starting model's rate of a signal (``T`` of ``T_dot``) whose equation reads an input, at the
    samples of a record where it is held (:mod:`~msam_torch.data.hold`): on either side of each sample
    (where the input switches, the rate jumps: the signal kinks), and its slope in the signal."""

    signal: str
    inputs: tuple[str, ...]  # the inputs the rate reads
    model: EquationModel  # the starting model of the signal's equation

    def at(self, measured: dict, k: np.ndarray, switching: list) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """At samples ``k``: the rate with the inputs of ``switching`` as held after the sample, as
        held before it (from the sample before; the first sample's own), and the rate's slope in the
        signal (all at the sample's state); None where the rate reads a signal the record lacks or
        cannot be evaluated there."""
        names = self.model.equation.signals - {self.model.equation.target, "t"}
        if not names <= set(measured):
            return None
        at = lambda n, i: torch.as_tensor(measured[n][i], dtype=torch.float64).unsqueeze(0)  # (1, K): one model row
        after = {n: at(n, k) for n in names}
        before = {**after, **{u: at(u, np.maximum(k - 1, 0)) for u in switching}}
        own = after[self.signal].clone().requires_grad_(True) if self.signal in names else None
        try:
            rate = self.model.rate({**after, **({} if own is None else {self.signal: own})})[0]
            earlier = self.model.rate(before)[0]
        except MSAMError:
            return None
        slope = None if own is None else torch.autograd.grad(rate.sum(), own, allow_unused=True)[0]
        slope = torch.zeros_like(rate) if slope is None else slope
        shaped = lambda v: v.detach().reshape(-1).broadcast_to(k.shape).numpy()
        return shaped(rate), shaped(earlier), shaped(slope)


def kinking(spec: ModelSpec, theta: Mapping[str, torch.Tensor] | None = None) -> dict[str, Kink]:
    """Per signal whose rate an equation gives (``T`` of ``T_dot``, ``x_dot`` of ``x_ddot``) and whose
    equation reads an input: its :class:`Kink` (where the input switches, the signal has a kink), the
    rate with the nominal theta or with ``theta`` (target -> theta of every component) where given."""
    out = {}
    for equation in spec.equations:
        base, order = split_derivative(equation.target)
        inputs = tuple(u for u in spec.inputs if u in equation.signals)
        if inputs:
            signal = derivative_name(base, order - 1)
            given = (theta or {}).get(equation.target)
            given = spec.theta(equation) if given is None else given
            out[signal] = Kink(signal, inputs, EquationModel.starting(equation, given))
    return out


def refitted(kinks: Mapping[str, Kink], signals: Mapping[str, torch.Tensor],
             half_width: float) -> dict[str, torch.Tensor]:
    """The theta of each kinking equation's starting components re-fitted to ``signals`` by least
    squares in the weak form (test functions of ``half_width``): the input coefficients that give a
    kink's jump, and the state's that gives its slope, as the record gives them rather than the
    nominal ones (:mod:`~msam_torch.data.hold`); an equation whose fit is not determined keeps its theta."""
    tests = TestFunctions.spanning(signals["t"], half_width)
    out = {}
    for kink in kinks.values():
        equation = kink.model.equation
        if not equation.signals <= set(signals):
            continue
        data = weak_data(equation, signals, tests, normalize="none")
        rows = torch.cat([data.unadjusted, data.fixed_components], -1)[0]  # (M, K): adjustable, then fixed
        scale = rows.norm(dim=0)
        if rows.shape[0] <= rows.shape[1] or not bool(torch.all(scale > 0) and torch.isfinite(rows).all()):
            continue
        fitted = torch.linalg.lstsq(rows / scale, data.y[0].unsqueeze(-1)).solution.squeeze(-1) / scale
        theta = torch.empty_like(fitted)
        theta[list(equation.adjustable) + list(equation.fixed)] = fitted
        if bool(torch.isfinite(theta).all()):
            out[equation.target] = theta.cpu().double()
    return out


def _signals(measured: dict, every: int, band: float, data: DataConfig, spec: ModelSpec, dtype,
             estimator: DerivativeEstimator, exact: bool, source: str, kinks: dict) -> tuple[dict, dict, dict]:
    """Decimated measured signals (held inputs as their quadrature values, the states' kinks at
    their switches corrected by ``kinks``, :mod:`~msam_torch.data.hold`) with the derivatives the model
    reads that they lack; how they were formed (the derivative estimates, each input's assumed
    hold, the kink-corrected signals); and, where the record is not decimated, the shapes of its
    held inputs and kink-corrected states between samples (:func:`_refined`): the held inputs' samples,
    the states' :class:`~msam_torch.data.hold.Sides`."""
    t = measured["t"][::every]
    raw = measured
    measured, held, kinks, sides = hold.represent(measured, spec.inputs, data.input_hold, kinks)
    shapes = {**{u: raw[u] for u, how in held.items() if how == "zoh"}, **sides} if every == 1 else {}
    kept = {k: decimate(v, every) for k, v in measured.items() if k != "t"}
    if exact:  # every signal given (noise-free simulation): nothing to estimate
        return ({"t": torch.tensor(t, dtype=dtype), **{k: torch.tensor(np.ascontiguousarray(v), dtype=dtype)
                                                        for k, v in kept.items()}},
                {"derivatives": "given", "input_hold": held, "kinks_corrected": kinks}, shapes)
    dataset = build_dataset(t, kept, data, spec, {}, dtype, source, InBand(estimator, min(band * every, 0.45)),
                            keep_measured=True)
    return (dataset.signals, {"derivatives": dataset.info["derivatives"], "input_hold": held, "kinks_corrected": kinks},
            shapes)


def choose(spec: ModelSpec, data: DataConfig, train: Dataset, held_out: Dataset | None,
           estimator: DerivativeEstimator, half_width: float | None = None, samples: int = SAMPLES,
           band: tuple[float, dict] | None = None, refine: bool = False) -> Estimation:
    """The band of ``train`` (``band`` as :func:`regressor_band` gives it, else that of its
    measured states, :func:`record_band`), the half-width (``half_width`` when given) and
    decimation it implies, and both records' weak-form signals on the training device; with
    ``refine``, interpolated between samples where a half-width holds fewer than
    :data:`QUADRATURE` of them (:func:`refined`)."""
    measured = _measured(train)
    t = measured["t"]
    dt = float(t[1] - t[0])
    band, edges = band or record_band(measured, spec.inputs)  # cycles per sample
    rule = "given" if half_width else f"band edge {band / dt:.4g} cycles per time unit"
    half_width = half_width_for(band / dt, t, half_width)
    every = max(1, min(t.size // samples, int(1 / (SAMPLES_PER_PERIOD * band)), int(half_width / (QUADRATURE * dt))))
    exact = not train.measured
    device, dtype = train.t.device, train.t.dtype
    def build(d: Dataset, source: str, kinks: dict) -> tuple[dict, dict, dict, float]:
        """A record's signals, decimated to about the training record's decimated sample time
        (rules in time units: a held-out record may be sampled at another rate)."""
        step = float(d.t[1] - d.t[0])
        k = max(1, round(every * dt / step))
        try:
            return (*_signals(_measured(d), k, DERIVATIVE_MARGIN * band * step / dt, data, spec, dtype, estimator,
                              exact, source, kinks), k * step)
        except DataError as error:
            raise DataError(f"after decimation by {k}: {error}") from None

    kinks = kinking(spec)
    signals, formed, shapes, period = build(train, "training data", kinks)
    if formed["kinks_corrected"]:  # again, with the jumps and slopes of the starting model re-fitted to the record
        kinks = kinking(spec, refitted(kinks, signals, half_width))
        signals, formed, shapes, period = build(train, "training data", kinks)
    other = None if held_out is None else build(held_out, "held-out data", kinks)
    # interpolated at most REFINE-fold, and to at most QUADRATURE * samples samples (the cost of every fit)
    budget = QUADRATURE * samples // signals["t"].shape[-1]
    fold = max(1, min(REFINE, math.ceil(QUADRATURE * period / half_width), budget)) if refine else 1
    refined_to = lambda d: _refined(*d[:3], max(1, round(fold * d[3] / period)), device)  # the same spacing
    signals, held = refined_to((signals, formed, shapes, period)), None if other is None else refined_to(other)
    form = "measured (unsmoothed)" if not exact else "given (exact)"
    how = {"band-limited": "band-limited", "linear": "linearly",
           "cubic": "by local cubics (held inputs as held, kinking states along the starting model's rates)"}[
        _between(_held(formed), not shapes)]
    info = {"band_edge": band / dt, "band_edges": {k: v / dt for k, v in edges.items()}, "half_width_rule": rule,
            "decimation": every, "derivative_cutoff": min(DERIVATIVE_MARGIN * band, 0.45) / dt,
            "weak_form_signals": form + (f", interpolated {how} {fold}-fold between samples" if fold > 1 else ""),
            "refinement": fold, **formed}
    if other is not None:  # each record's inputs as it holds them (a held-out record may be stepped where training is smooth)
        info["held_out_input_hold"] = other[1]["input_hold"]
    return Estimation(signals, held, half_width, every, info, fold)


def _held(formed: dict) -> bool:
    return any(b == "zoh" for b in formed["input_hold"].values())


def _between(held: bool, decimated: bool) -> str:
    """The shape (:func:`refined`) of a record's signals between samples: band-limited where no input
    is held; local cubics where one is, linear where that record was also decimated (its kinks
    smeared by the anti-alias filter, its shapes unknown)."""
    return "band-limited" if not held else "linear" if decimated else "cubic"


def _refined(signals: dict, formed: dict, shapes: dict, k: int, device) -> dict:
    """A record's weak-form signals on ``device``, interpolated ``k``-fold (:func:`refined`):
    band-limited where no input is held; where one is (its states kink at every switch, and a
    band-limited interpolation rings there), by their ``shapes`` between samples (:func:`_signals`):
    a kinking state along the starting model's rates (:func:`~msam_torch.data.hold.hermite`), a held
    input as held (:func:`~msam_torch.data.hold.held_finer`), every other signal by local cubics
    (:func:`~msam_torch.data.hold.local_cubic`), so that every signal is as exact between samples as the
    others (a straight line between samples is the samples seen through a wider test function, and
    the quadrature is consistent only where every signal is seen through it); linearly where the
    record was decimated (no shapes)."""
    if k <= 1:
        return {name: v.to(device) for name, v in signals.items()}
    shape = _between(_held(formed), not shapes)
    out = {name: refined(v.to(device), k, "linear" if name == "t" else shape) for name, v in signals.items()}
    dt = float(signals["t"][1] - signals["t"][0])
    for name, given in shapes.items():
        fine = hold.hermite(given, k, dt) if isinstance(given, hold.Sides) else hold.held_finer(given, k)
        out[name] = torch.as_tensor(fine, dtype=out[name].dtype, device=device)
    return out


def refined(signal: torch.Tensor, k: int, shape: str = "linear") -> torch.Tensor:
    """A signal (time on its last axis) interpolated ``k``-fold between its samples: where a
    half-width holds fewer than :data:`QUADRATURE` samples, the weak form's quadrature of a candidate
    function (``sign(v)`` of a speed that reverses within a few samples) needs points between them.
    ``shape``: ``linear``, ``cubic`` (local cubics, :func:`~msam_torch.data.hold.local_cubic`) or
    ``band-limited`` (the polyphase low-pass of :func:`~msam_torch.data.filters.resample`); the last two keep
    a smooth function of a signal within a few tenths of a percent of its weak form where linear
    interpolation is off by several percent."""
    if k <= 1:
        return signal
    n = signal.shape[-1]
    if shape != "linear":
        values = signal.detach().cpu().numpy()
        fine = (resample(values, k, 1)[..., :(n - 1) * k + 1] if shape == "band-limited"
                else hold.local_cubic(values, k))
        return torch.as_tensor(np.ascontiguousarray(fine), dtype=signal.dtype, device=signal.device)
    position = torch.arange((n - 1) * k + 1, device=signal.device, dtype=torch.float64) / k
    left = position.floor().long().clamp(max=n - 2)
    w = (position - left).to(signal.dtype)
    return signal[..., left] * (1 - w) + signal[..., left + 1] * w
