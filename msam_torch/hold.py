"""How an input behaves between its samples (its intersample behaviour), for the weak form's
quadrature (:mod:`msam_torch.estimation`).

A digital controller or signal generator holds each value until the next sample (zero-order
hold: ``u(t) = u_k`` for ``t_k <= t < t_{k+1}``), so the input the system feels is piecewise
constant; the trapezoid rule on the samples (linear interpolation between them) moves every
switch by half a sample, an error no smoother of the states can remove. Over the cell
``[t_k - dt/2, t_k + dt/2]`` the held input averages ``(u_{k-1} + u_k) / 2``; the trapezoid rule on
these cell averages integrates the held input against a smooth test function to second order
(Pintelon and Schoukens, System Identification: A Frequency Domain Approach, 2nd ed., Wiley 2012,
section 13.2, on zero-order-hold and band-limited intersample behaviour).

``data.input_hold``: ``zoh``, ``linear`` (the samples of a continuous signal) or ``auto``: held
for an input that changes at no more than :data:`HELD_SHARE` of its sample steps (a sampled
continuous signal changes at nearly every sample; a held one keeps each value for two samples
or more), else linear.
"""
from __future__ import annotations

import numpy as np

HELD_SHARE = 0.5


def is_held(u: np.ndarray) -> bool:
    """A piecewise-constant input: it changes, at no more than :data:`HELD_SHARE` of its steps."""
    changes = np.diff(np.asarray(u)) != 0
    return bool(changes.any()) and float(changes.mean()) <= HELD_SHARE


def cell_averages(u: np.ndarray) -> np.ndarray:
    """A zero-order-held input's average over each sample's cell: ``(u_{k-1} + u_k) / 2`` (the
    first sample: ``u_0``)."""
    u = np.asarray(u, dtype=float)
    return np.concatenate([u[:1], 0.5 * (u[:-1] + u[1:])])


def represent(measured: dict, inputs, rule: str) -> tuple[dict, dict]:
    """``measured`` with every held input (``rule``: ``zoh``, ``linear`` or ``auto``, see the module)
    replaced by its cell averages, and the behaviour assumed per input."""
    behaviour = {u: ("zoh" if rule == "zoh" or (rule == "auto" and is_held(measured[u])) else "linear")
                 for u in inputs if u in measured}
    return {k: cell_averages(v) if behaviour.get(k) == "zoh" else v for k, v in measured.items()}, behaviour
