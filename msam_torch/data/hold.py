"""How an input behaves between its samples (its intersample behaviour), for the weak form's
quadrature (:mod:`msam_torch.run.estimation`).

A digital controller or signal generator holds each value until the next sample (zero-order
hold: ``u(t) = u_k`` for ``t_k <= t < t_{k+1}``), so the input the system feels is piecewise
constant; the trapezoid rule on the samples (linear interpolation between them) moves every
switch by half a sample, an error no smoother of the states can remove (Pintelon and Schoukens,
System Identification: A Frequency Domain Approach, 2nd ed., Wiley 2012, section 13.2, on
zero-order-hold and band-limited intersample behaviour). The exact integral against a smooth test
function ``phi`` is ``sum_k u_k int_{t_k}^{t_{k+1}} phi dt``; the Euler-Maclaurin formula on each
cell, ``dt (phi_k + phi_{k+1}) / 2 - dt^2 (phi'_{k+1} - phi'_k) / 12``, with ``phi'`` by central
differences and summed by parts, turns it into the trapezoid rule on the *quadrature values*
``(-u_{k-2} + 13 u_{k-1} + 13 u_k - u_{k+1}) / 24``: fourth order in the sample step, where the
cell averages ``(u_{k-1} + u_k) / 2`` (the first two terms alone) are second order (against a
bump of 5 samples' half-width: 0.3 % error instead of 2.4 %).

Where a held input switches, the rate of a state whose equation reads it jumps: the state has a
kink there, and the trapezoid rule on any function ``g`` of it misses ``[g'] tau^2 ((r/2)
coth(r/2) - 1)`` at that sample (``[g']`` the jump of the slope, ``tau`` the time constant at which
the state relaxes after it, ``r = dt / tau``; ``dt^2 [g'] / 12`` when ``r`` is small: the
Euler-Maclaurin term), whatever the test function's width. The state's sample at the switch moved
by ``dt [x'] rho(r) / 12``, ``rho(r) = 12 ((r/2) coth(r/2) - 1) / r^2``, restores it for every
function of the state at once, to first order (:func:`kink_corrected`). The jump ``[x']`` and the
rate's slope ``-1/tau`` are the starting model's (:class:`~msam_torch.run.estimation.Kink`): the
rate after the switch less the rate before, at the same state. The unmodelled effect is a function
of the states, which do not jump, so the jump is the input terms' alone, known to the accuracy of
their coefficients, and free of the noise that a second difference of the samples doubles (and of
its bias where the state relaxes within a few samples: a second difference sees ``(1 - e^-r) / r``
of the jump). The coefficients are the starting model's re-fitted to the record
(:func:`~msam_torch.run.estimation.refitted`, on the record corrected with the nominal ones): a
nominal input gain 20 % off leaves 20 % of every kink's error, enough to move radiation's
exponent by 0.2. A state that settles within half a sample (``r >``
:data:`SAMPLED`) is left as it is: its transient is not sampled, and the first-order correction
overshoots. On ``x' = -a x + b u`` under a PRBS, nominal coefficients 10 % off, the correction
leaves a tenth of the trapezoid rule's error on ``x^2`` for ``r`` from 0.04 to 1.1
(``tests/data/test_hold.py``).

The correction is exact for a test function that is constant over the relaxation. A test function
only a few samples wide changes across it, and a record interpolated between its samples for such
test functions (:func:`~msam_torch.run.estimation.refined`) gets the state's shape between samples
instead (:func:`hermite`): in each cell, the cubic through the two samples with the starting
model's rates at either end under the input held over the cell (:class:`Sides`), which follows
``e^(-r s)`` within 1.6 % of the cell's change for ``r`` up to :data:`SAMPLED` where the straight
line is off by 20 %; the kink then sits on a node of the fine grid and is corrected there, at the
fine step. An error of the rates that changes little from one sample to the next (an effect of
slowly varying states that the starting model misses) moves both ends of a cell alike, and the
cubic only by a wiggle of zero mean in each cell. The other signals follow local cubics of their own
samples (:func:`local_cubic`): a rate that reads a fast state (a motor's current, in its speed's
equation) carries the errors of that state's coefficient from sample to sample.

``data.input_hold``: ``zoh``, ``linear`` (the samples of a continuous signal) or ``auto``: held
for an input that changes at no more than :data:`HELD_SHARE` of its sample steps (a sampled
continuous signal changes at nearly every sample; a held one keeps each value for two samples
or more), else linear.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HELD_SHARE = 0.5
SAMPLED = 2.0  # kinks are corrected where the state's time constant is at least 1 / SAMPLED samples


def is_held(u: np.ndarray) -> bool:
    """A piecewise-constant input: it changes, at no more than :data:`HELD_SHARE` of its steps."""
    changes = np.diff(np.asarray(u)) != 0
    return bool(changes.any()) and float(changes.mean()) <= HELD_SHARE


def quadrature_values(u: np.ndarray) -> np.ndarray:
    """A zero-order-held input's values for the trapezoid rule (module docstring): at sample ``k``,
    ``(-u_{k-2} + 13 u_{k-1} + 13 u_k - u_{k+1}) / 24``, the record's ends repeated outward."""
    u = np.asarray(u, dtype=float)
    p = np.concatenate([u[:1], u[:1], u, u[-1:]])
    return (-p[:-3] + 13.0 * p[1:-2] + 13.0 * p[2:-1] - p[3:]) / 24.0


def kink_corrected(x: np.ndarray, k: np.ndarray, jump: np.ndarray, slope: np.ndarray, dt: float) -> np.ndarray | None:
    """``x`` with its samples ``k`` (interior switches) moved by ``dt jump rho(r) / 12``, ``r = dt |slope|``
    (module docstring): the trapezoid rule's missing term at a kink of slope jump ``jump`` after which
    the state relaxes at rate ``slope``. Only where ``r`` <= :data:`SAMPLED`; None where no sample moves."""
    r = dt * np.abs(slope)
    sampled = np.isfinite(jump) & (r <= SAMPLED)
    if not sampled.any():
        return None
    half = np.maximum(r / 2.0, 1e-4)
    rho = np.where(r < 1e-3, 1.0, 12.0 * (half / np.tanh(half) - 1.0) / np.maximum(r, 1e-3) ** 2)
    out = np.asarray(x, dtype=float).copy()
    out[k[sampled]] += dt * jump[sampled] * rho[sampled] / 12.0
    return out


@dataclass(frozen=True)
class Sides:
    """A kinking state as recorded (``samples``, N) with the starting model's rate at each sample
    under the held inputs of the cell before it (``before``) and of the cell after it (``after``),
    and the rate's slope in the state (``slope``)."""

    samples: np.ndarray
    before: np.ndarray
    after: np.ndarray
    slope: np.ndarray

    def switches(self) -> np.ndarray:
        """Interior samples where the rate jumps (a held input switched)."""
        k = np.flatnonzero(self.after != self.before)
        return k[(k > 0) & (k < self.samples.size - 1)]


def cubic(x: np.ndarray, start: np.ndarray, end: np.ndarray, k: int) -> np.ndarray:
    """Samples ``x`` (time on the last axis, N) interpolated ``k``-fold by a cubic per cell: through
    the cell's two samples with rates (per sample step, N - 1 each) ``start`` and ``end`` at its
    ends (rates equal to the cell's change give its straight line)."""
    n = x.shape[-1]
    s = (np.arange((n - 1) * k) % k) / k
    m = np.arange((n - 1) * k) // k
    a, b = x[..., m], x[..., m + 1]
    fine = a + (3 * s**2 - 2 * s**3) * (b - a) + (s**3 - 2 * s**2 + s) * start[..., m] + (s**3 - s**2) * end[..., m]
    return np.concatenate([fine, x[..., -1:]], axis=-1)


def local_cubic(x: np.ndarray, k: int) -> np.ndarray:
    """Samples ``x`` (time on the last axis, at least 3) interpolated ``k``-fold by :func:`cubic` with
    each sample's rate by the fourth-order central difference (the record's ends reflected oddly):
    as close as a cubic spline on a smooth signal, and local, so that a kink between two samples
    (a speed reversing under Coulomb friction) bends only the cells beside it, where a spline rings
    through the record."""
    p = np.concatenate([2 * x[..., :1] - x[..., 2:0:-1], x, 2 * x[..., -1:] - x[..., -2:-4:-1]], axis=-1)
    rate = (-p[..., 4:] + 8 * p[..., 3:-1] - 8 * p[..., 1:-3] + p[..., :-4]) / 12
    return cubic(x, rate[..., :-1], rate[..., 1:], k)


def hermite(sides: Sides, k: int, dt: float) -> np.ndarray:
    """``sides``' state interpolated ``k``-fold between its samples (module docstring): per cell,
    the cubic with end rates ``after`` (start) and ``before`` (end), where the cell's ``r = dt
    |slope|`` is at most :data:`SAMPLED`, else the straight line; then each switch's kink corrected
    at the fine step (:func:`kink_corrected`)."""
    x = sides.samples
    sampled = np.abs(dt * sides.slope) <= SAMPLED
    chord = np.diff(x)
    fine = cubic(x, np.where(sampled[:-1], dt * sides.after[:-1], chord),
                 np.where(sampled[:-1], dt * sides.before[1:], chord), k)
    switches = sides.switches()
    switches = switches[sampled[switches]]
    corrected = kink_corrected(fine, k * switches, (sides.after - sides.before)[switches], sides.slope[switches],
                               dt / k) if switches.size else None
    return fine if corrected is None else corrected


def held_finer(u: np.ndarray, k: int) -> np.ndarray:
    """A held input's quadrature values (:func:`quadrature_values`) on a grid ``k`` times finer than
    its samples ``u``: it holds each sample over the ``k`` fine cells of its own cell."""
    return quadrature_values(np.repeat(np.asarray(u, dtype=float), k)[:(len(u) - 1) * k + 1])


def represent(measured: dict, inputs, rule: str, kinks: dict | None = None) -> tuple[dict, dict, list, dict]:
    """``measured`` with every held input (``rule``: ``zoh``, ``linear`` or ``auto``, see the module)
    replaced by its quadrature values and every signal of ``kinks`` (signal -> its
    :class:`~msam_torch.run.estimation.Kink`) corrected where a held input its rate reads switches; the
    behaviour assumed per input, the signals corrected, and their :class:`Sides`."""
    behaviour = {u: ("zoh" if rule == "zoh" or (rule == "auto" and is_held(measured[u])) else "linear")
                 for u in inputs if u in measured}
    out = {k: quadrature_values(v) if behaviour.get(k) == "zoh" else v for k, v in measured.items()}
    switches = {u: np.diff(measured[u], prepend=measured[u][:1]) != 0 for u, b in behaviour.items() if b == "zoh"}
    dt = float(np.median(np.diff(measured["t"]))) if kinks else 0.0
    corrected, sides = [], {}
    for x, kink in (kinks or {}).items():
        switching = [u for u in kink.inputs if u in switches]
        if x not in measured or not switching:
            continue
        found = kink.at(measured, np.arange(measured[x].size), switching)
        if found is None:
            continue
        after, before, slope = found
        sides[x] = Sides(np.asarray(measured[x], dtype=float), before, after, slope)
        k = sides[x].switches()
        fixed = kink_corrected(measured[x], k, (after - before)[k], slope[k], dt) if k.size else None
        if fixed is not None:
            out[x] = fixed
            corrected.append(x)
    return out, behaviour, corrected, sides
