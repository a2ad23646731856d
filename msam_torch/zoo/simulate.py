"""The truth simulated with ``scipy.integrate.solve_ivp`` (tight tolerances, inputs interpolated
on a dense grid), independently of :mod:`msam_torch.simulation`; and the share of the dynamics a
withheld effect contributes."""
from __future__ import annotations

from bisect import bisect_right

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from msam_torch.zoo.system import System, term_value

DENSE = 8  # dense input samples per sample interval
TOLERANCE = 1e-8  # relative; absolute: 1e-2 of it times each state's typical size


def simulate(system: System, t: np.ndarray, inputs: dict, initial: dict, effect=None,
             smooth: frozenset = frozenset()) -> dict | None:
    """States on grid ``t`` under ``inputs`` (arrays on ``t``'s dense grid ``dense_grid(t)``,
    interpolated by cubic splines for the ``smooth`` ones, else held from each dense point to the
    next); None when the solver fails or a trajectory leaves the finite numbers."""
    dense = dense_grid(t)
    interpolants = {u: _spline(dense, v) if u in smooth else _held(dense, v) for u, v in inputs.items()}
    derivative = system.derivative_map()
    states = list(system.states)
    atol = [TOLERANCE * 1e-2 * system.magnitude[x] for x in states]

    def rhs(time, y):
        values = {x: v for x, v in zip(states, y)}
        values.update({u: interpolants[u](time) for u in system.inputs})
        rates = system.state_rates(values, effect)
        return [values[derivative[x]] if derivative[x] in values else rates[derivative[x]] for x in states]

    dt = t[1] - t[0]
    solution = solve_ivp(rhs, (t[0], t[-1]), [initial[x] for x in states], t_eval=t, method="LSODA",
                         rtol=TOLERANCE, atol=atol, max_step=dt)
    if not solution.success or not np.all(np.isfinite(solution.y)) or solution.y.shape[1] != t.size:
        return None
    return dict(zip(states, solution.y))


def _held(grid: np.ndarray, values: np.ndarray):
    """``interp1d(grid, values, kind="previous")`` at one time, without its per-call array overhead
    (the solver asks about a hundred thousand times a case): the value at the last grid point at or
    before ``time``."""
    points, values = grid.tolist(), values.tolist()
    return lambda time: values[max(bisect_right(points, time), 1) - 1]


def _spline(grid: np.ndarray, values: np.ndarray):
    """The not-a-knot :class:`~scipy.interpolate.CubicSpline` through ``values`` at one time: its
    pieces' coefficients evaluated by Horner's rule in the piece holding ``time`` (the last piece
    at the grid's end)."""
    spline = CubicSpline(grid, values)
    points, pieces = grid.tolist(), spline.c.T.tolist()
    last = len(pieces) - 1

    def value(time):
        i = min(max(bisect_right(points, time) - 1, 0), last)
        s = time - points[i]
        c3, c2, c1, c0 = pieces[i]
        return ((c3 * s + c2) * s + c1) * s + c0

    return value


def dense_grid(t: np.ndarray) -> np.ndarray:
    return np.linspace(t[0], t[-1], (t.size - 1) * DENSE + 1)


def signals(system: System, states: dict, inputs: dict, t: np.ndarray) -> dict:
    """States and the inputs resampled from the dense grid onto ``t``."""
    dense = dense_grid(t)
    return {**states, **{u: np.interp(t, dense, inputs[u]) for u in system.inputs}}


def effect_share(system: System, values: dict, effect, felt: dict | None = None) -> dict:
    """Per equation: RMS of the part of the effect's contribution that re-fitting the starting
    model's theta cannot absorb (least-squares residual on the starting components), relative to
    the RMS of the true rate. ``felt``: the inputs the system feels (input nonlinearities)."""
    truth_values = {**values, **(felt or {})}
    true_rates = system.state_rates(truth_values, effect)
    start_rates = system.state_rates(values)
    out = {}
    for eq in system.equations:
        left = unabsorbed(eq, values, true_rates[eq.target] - start_rates[eq.target])
        out[eq.target] = float(rms(left) / rms(true_rates[eq.target]))
    return out


def unabsorbed(eq, values: dict, contribution) -> np.ndarray:
    """``contribution`` less its least-squares fit by the starting components of ``eq``."""
    shape = np.shape(values[next(iter(values))])
    contribution = np.broadcast_to(contribution, shape)
    basis = np.stack([np.broadcast_to(term_value(m, values), shape) for m in eq.terms], -1)
    coef, *_ = np.linalg.lstsq(basis, contribution, rcond=None)
    return contribution - basis @ coef


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))
