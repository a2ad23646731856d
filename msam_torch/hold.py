"""How an input behaves between its samples (its intersample behaviour), for the weak form's
quadrature (:mod:`msam_torch.estimation`).

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
kink there, and the trapezoid rule on any function ``g`` of it misses ``dt^2 [g'] / 12`` at that
sample (Euler-Maclaurin, ``[g']`` the jump of the slope), whatever the test function's width. The
kink's slope jump is read from the data, ``[x'] ~ (x_{k+1} - 2 x_k + x_{k-1}) / dt``, and the
state's sample there moved by ``dt [x'] / 12`` (:func:`kink_corrected`): for every function of
the state at once, the trapezoid rule then gets the missing term to first order. On a first-order
heated body under a PRBS (sampled at 0.1-0.3 of its time constant) the weak-form equation error of
the true model falls from 1.5 % to 0.3 % of the target's RMS (half-widths of 10-20 samples).

``data.input_hold``: ``zoh``, ``linear`` (the samples of a continuous signal) or ``auto``: held
for an input that changes at no more than :data:`HELD_SHARE` of its sample steps (a sampled
continuous signal changes at nearly every sample; a held one keeps each value for two samples
or more), else linear.
"""
from __future__ import annotations

import numpy as np

HELD_SHARE = 0.5
RESOLVED = 0.5  # a kink stands out of the second differences by at least 1 / RESOLVED


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


def kink_corrected(x: np.ndarray, switches: np.ndarray) -> np.ndarray | None:
    """``x`` with each interior sample at a switch (boolean mask) moved by its second difference
    over 12: the trapezoid rule's missing term at a kink (module docstring). None where the data
    show no resolved kinks: the second differences one sample after the switches (the state's own
    curvature, or noise) are, in median, at least :data:`RESOLVED` of those at the switches (a
    state that settles within a sample, or a noisy one: the jump read from them would be wrong)."""
    x = np.asarray(x, dtype=float)
    second = np.zeros_like(x)
    second[1:-1] = x[2:] - 2.0 * x[1:-1] + x[:-2]
    inner = switches.copy()
    inner[[0, -1]] = False
    k = np.flatnonzero(inner)
    after = np.setdiff1d(k + 1, k)
    after = after[after < x.size - 1]
    if k.size == 0 or after.size == 0 or np.median(np.abs(second[after])) >= RESOLVED * np.median(np.abs(second[k])):
        return None
    out = x.copy()
    out[k] += second[k] / 12.0
    return out


def represent(measured: dict, inputs, rule: str, kinks: dict | None = None) -> tuple[dict, dict, list]:
    """``measured`` with every held input (``rule``: ``zoh``, ``linear`` or ``auto``, see the module)
    replaced by its quadrature values and every signal of ``kinks`` (signal -> the inputs its rate
    reads) corrected where one of them, held, switches and the kinks are resolved; the behaviour
    assumed per input, and the signals corrected."""
    behaviour = {u: ("zoh" if rule == "zoh" or (rule == "auto" and is_held(measured[u])) else "linear")
                 for u in inputs if u in measured}
    out = {k: quadrature_values(v) if behaviour.get(k) == "zoh" else v for k, v in measured.items()}
    switches = {u: np.diff(measured[u], prepend=measured[u][:1]) != 0 for u, b in behaviour.items() if b == "zoh"}
    corrected = []
    for x, read in (kinks or {}).items():
        switching = [switches[u] for u in read if u in switches]
        fixed = kink_corrected(measured[x], np.any(switching, axis=0)) if x in measured and switching else None
        if fixed is not None:
            out[x] = fixed
            corrected.append(x)
    return out, behaviour, corrected
