"""The one ``simulate()``: a model of Eq. 9 integrated over a record with torchdiffeq.

Fixed-step solvers (``rk4``, ``midpoint``, ``euler``) look the external signals up in a table
interpolated once at the solver's stage times (sixths of a step); torch.func transforms (``jvp``,
``jacfwd``) pass through them, which the sensitivities rely on. Adaptive solvers (``dopri5``, ...)
interpolate at every stage and fall back to ``rk4`` when their step underflows. Small batches run
on one CPU thread. A trajectory that leaves ``span`` is frozen there and returned as NaN, so one
diverging member neither crashes nor stalls the batch.
"""
from __future__ import annotations

from contextlib import contextmanager

import math
import torch
from torchdiffeq import odeint

from .model import Parameters, SystemModel
from .record import Record

FIXED_STEP = ("euler", "midpoint", "rk4")
SERIAL_ELEMENTS = 32768  # batches of fewer state values are simulated on one thread (torch's grain size)


def simulate(model: SystemModel, record: Record, p: Parameters, x0: torch.Tensor, method: str = "rk4",
             substeps: int = 1, limits: torch.Tensor | None = None, span: torch.Tensor | None = None,
             step: float | None = None, rtol: float = 1e-6, atol: float = 1e-9) -> torch.Tensor:
    """Integrate ``model`` from ``x0`` (B, S) over the record: states (B, N, S).

    ``step``: the fixed step (default: the sample period over ``substeps``); ``rtol``, ``atol``:
    adaptive solvers. ``limits`` (2, S): a state's rate is zero while the state is at or beyond a
    limit and the rate points outwards (``simulation.saturation``). ``span`` (S,): a row whose
    state leaves ``|x| < span`` is diverged, frozen and returned as NaN.
    """
    rates = model.rhs(p, x0.dtype, x0.device)
    t0 = float(record.t[0])
    step = step or float(record.t[1] - record.t[0]) / substeps
    fixed = method in FIXED_STEP
    if fixed:
        sixths = math.ceil((float(record.t[-1]) - t0) / step * 6 - 1e-9) + 1
        table = record.at(record.t[0] + torch.arange(sixths, dtype=record.t.dtype, device=record.t.device) * (step / 6))
        columns = table.unbind(-1)

    def func(t, x):
        if fixed:
            key = min(max(round((float(t) - t0) / step * 6), 0), sixths - 1)
            external = [c[..., key] for c in columns]
        else:
            external = record.at(t.reshape(1)).squeeze(-2).unbind(-1)
        values = {"t": t, **dict(zip(model.states, x.unbind(-1))), **dict(zip(model.external, external))}
        rate = rates(values, x)
        if limits is not None:
            held = ((x >= limits[1]) & (rate > 0)) | ((x <= limits[0]) & (rate < 0))
            rate = torch.where(held, torch.zeros_like(rate), rate)
        if span is not None:
            alive = (x.abs() < span).all(-1, keepdim=True) & torch.isfinite(rate).all(-1, keepdim=True)
            rate = torch.where(alive, rate, torch.zeros_like(rate))
        return rate

    with _single_thread(x0.numel() < SERIAL_ELEMENTS and x0.device.type == "cpu"):
        if fixed:
            trajectory = odeint(func, x0, record.t, method=method, options={"step_size": step})
        else:
            try:
                trajectory = odeint(func, x0, record.t, method=method, rtol=rtol, atol=atol)
            except AssertionError:  # torchdiffeq's step-size underflow: integrate with fixed steps instead
                return simulate(model, record, p, x0, "rk4", substeps, limits, span, step)
    states = trajectory.movedim(0, -2)
    if span is None:
        return states
    diverged = ~(states.abs() < span).all(-1).all(-1)  # (B,)
    return torch.where(diverged.view(-1, 1, 1), torch.full_like(states, torch.nan), states)


@contextmanager
def _single_thread(serial: bool):
    """Run a simulation of a small batch on one CPU thread: its thousands of tiny per-stage
    operations gain nothing from intra-op threads and lose much to their synchronisation
    (tenfold when the other cores are busy). The thread count is restored."""
    threads = torch.get_num_threads()
    if serial and threads > 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
