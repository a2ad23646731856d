"""The one ``simulate()``: a model of Eq. 9 integrated over a record.

Fixed-step methods (``euler``, ``midpoint``, ``rk4``: torchdiffeq's tableaus, ``rk4`` its 3/8
rule) run as an explicit Runge-Kutta loop whose step coefficients are tensors derived from the
record's time axis; the external signals are interpolated once at all stage times (sixths of a
step), and every expression of the model that reads no simulated state is tabulated there once
(:meth:`~.model.SystemModel.stage_rates`), so a stage evaluates only what depends on the states.
Forward-mode differentiation (:mod:`.sensitivities`) passes through with every operation between
dual tensors: torchdiffeq's fixed-grid steps multiply by Python numbers, an operation forward mode
runs on a slow path (about 0.7 ms against 10 us between dual tensors), which made differentiating
through torchdiffeq's ``rk4`` 15 to 30 times the cost of the simulation. Adaptive methods
(``dopri5``, ...) are torchdiffeq's, and fall back to ``rk4`` when their step underflows. Small
batches run on one CPU thread. A trajectory that leaves ``span`` is returned as NaN, so one
diverging member neither crashes nor stalls the batch: an adaptive method freezes it where it
leaves (its step would otherwise shrink for every member); the fixed-step loop, whose members
never share a step, lets it run on and marks it once at the end (a check per stage cost about a
fifth of the loop). A long fixed-step run that is not differentiated is cut into segments
integrated side by side, each restarted from the end of the one before until they join
(:func:`segments`): the loop's cost is its per-stage overhead, nearly the same for one row as for
hundreds.
"""
from __future__ import annotations

from contextlib import contextmanager

import torch
import torch.autograd.forward_ad as forward_ad
from torchdiffeq import odeint

from .model import Parameters, SystemModel
from .record import Record

# Explicit Runge-Kutta tableaus: stage times (sixths of a step), stage coefficients, weights.
TABLEAUS = {
    "euler": ((0,), ((),), (1.0,)),
    "midpoint": ((0, 3), ((), (0.5,)), (0.0, 1.0)),
    "rk4": ((0, 2, 4, 6), ((), (1 / 3,), (-1 / 3, 1.0), (1.0, -1.0, 1.0)), (0.125, 0.375, 0.375, 0.125)),
}
# The real interval of each tableau's stability region: a decaying mode lambda stays stable for
# h |lambda| within it (every 4-stage fourth-order method has the stability polynomial of rk4).
STABILITY = {"euler": 2.0, "midpoint": 2.0, "rk4": 2.785}
SERIAL_ELEMENTS = 32768  # batches of fewer state values are simulated on one thread (torch's grain size)
READ_BEFORE = 1e-6  # a step's last stage reads the external signals this share of a step before it
SEGMENT_STEPS = 500  # a fixed-step run is cut into segments of at least this many steps ...
SEGMENTS = 64  # ... and at most this many (see :func:`segments`)


def simulate(model: SystemModel, record: Record, p: Parameters, x0: torch.Tensor, method: str = "rk4",
             substeps: int = 1, limits: torch.Tensor | None = None, span: torch.Tensor | None = None,
             step: float | None = None, rtol: float = 1e-6, atol: float = 1e-9) -> torch.Tensor:
    """Integrate ``model`` from ``x0`` (B, S) over the record: states (B, N, S).

    ``step``: the fixed step (default: the sample period over ``substeps``); ``rtol``, ``atol``:
    adaptive methods. ``limits`` (2, S): a state's rate is zero while the state is at or beyond a
    limit and the rate points outwards (``simulation.saturation``). ``span`` (S,): a row whose
    state leaves ``|x| < span`` (or whose rate is not finite, under an adaptive method) is
    diverged and returned as NaN.
    """
    def guarded(rate, frozen_beyond=None):  # ``rate(time, x)`` (a time or a stage index) within the limits
        def func(t, x):  # ... and zero for a row beyond ``frozen_beyond`` (S,) or with a rate not finite
            rates = rate(t, x)
            if limits is not None:
                held = ((x >= limits[1]) & (rates > 0)) | ((x <= limits[0]) & (rates < 0))
                rates = torch.where(held, 0.0, rates)
            if frozen_beyond is not None:
                alive = (x.abs() < frozen_beyond).all(-1, keepdim=True) & torch.isfinite(rates).all(-1, keepdim=True)
                rates = torch.where(alive, rates, 0.0)
            return rates
        return func

    with _single_thread(x0.numel() < SERIAL_ELEMENTS and x0.device.type == "cpu"):
        if method in TABLEAUS:
            states = _runge_kutta(model, p, record, x0, TABLEAUS[method], substeps, step, guarded, span)
        else:
            rhs = model.rhs(p, x0.dtype, x0.device)
            values = lambda t, x: model.values(t, x, record.at(t.reshape(1)).squeeze(-2))
            try:
                states = odeint(guarded(lambda t, x: rhs(values(t, x), x), span), x0, record.t, method=method,
                                rtol=rtol, atol=atol).movedim(0, -2)
            except AssertionError:  # torchdiffeq's step-size underflow: integrate with fixed steps instead
                return simulate(model, record, p, x0, "rk4", substeps, limits, span, step)
    if span is None:
        return states
    diverged = ~(states.abs() < span).all(-1).all(-1)  # (B,)
    return torch.where(diverged.view(-1, 1, 1), torch.full_like(states, torch.nan), states)


def _runge_kutta(model: SystemModel, p: Parameters, record: Record, x0: torch.Tensor, tableau, substeps: int,
                 step: float | None, guarded, span: torch.Tensor | None) -> torch.Tensor:
    """The explicit Runge-Kutta loop on the grid ``t0 + i h`` (h = ``step`` or the sample period
    over ``substeps``), states at the record's times (interpolated linearly between grid points
    that miss them): (B, N, S). The external signals are interpolated at all stage times at once;
    a stage costs the model's per-stage operations. A stage at the end of a step reads the external
    signals just before it (their left limit): a held input that switches there is not read by
    the step it ends. A long run that is not differentiated runs in :func:`segments`."""
    offsets, stages, weights = tableau
    t = record.t
    h = (t[1] - t[0]) / substeps if step is None else torch.as_tensor(step, dtype=t.dtype, device=t.device)
    steps = int(torch.ceil((t[-1] - t[0]) / h - 1e-9))
    parts = segments(steps, x0, p, record)
    length = -(-steps // parts)  # steps per segment; the last one's beyond the record read its end
    offset = torch.tensor(offsets, device=t.device)
    keys = (6 * torch.arange(parts * length, device=t.device).unsqueeze(-1) + offset).flatten()  # in the loop's order
    stage_times = t[0] + keys.to(t.dtype) * (h / 6)
    ends = (offset == 6).repeat(parts * length)  # a step's last stage reads its own input
    read_at = torch.where(ends, stage_times - h * READ_BEFORE, stage_times).clamp(max=t[-1])
    func = guarded(model.stage_rates(p, stage_times, record.at(read_at), parts))
    coefficients = [[h * a for a in row] for row in stages]
    weights = [(h * b, b) for b in weights]

    def run(x):  # ``length`` steps from x: (..., length + 1, S)
        grid, j = [x], 0
        for _ in range(length):
            k = []
            for row in coefficients:
                stage = x
                for a, kj in zip(row, k):
                    stage = stage + kj * a
                k.append(func(j, stage))
                j += 1
            for (b, nonzero), kj in zip(weights, k):
                if nonzero:
                    x = x + kj * b
            grid.append(x)
        return torch.stack(grid, -2)

    if parts == 1:
        grid = run(x0)  # (B, steps + 1, S)
    else:  # every segment from the end of the one before it, until they join (Parareal without its coarse solver)
        first = x0.unsqueeze(-2)
        starts = first.expand(x0.shape[:-1] + (parts, x0.shape[-1]))  # the first guess of every segment's start
        for _ in range(parts):  # after k passes the first k segments are exact: at most ``parts`` passes
            grid = run(starts)  # (B, parts, length + 1, S)
            joined = torch.cat([first, grid[..., :-1, -1, :]], -2)
            if _joined(joined, starts, span):
                break
            starts = joined
        grid = torch.cat([grid[..., :-1, :].flatten(-3, -2), grid[..., -1:, -1, :]], -2)[..., :steps + 1, :]
    position = ((t - t[0]) / h).detach()
    nearest = position.round()
    if bool(((position - nearest).abs() < 1e-6).all()):
        return grid[..., nearest.long().clamp(max=steps), :]
    k = position.floor().long().clamp(max=steps - 1)
    w = (position - k).unsqueeze(-1)
    return grid[..., k, :] * (1 - w) + grid[..., k + 1, :] * w


def segments(steps: int, x0: torch.Tensor, p: Parameters, record: Record) -> int:
    """How many segments a fixed-step run integrates side by side: a Python loop of tiny operations
    costs about the same for one row as for hundreds, so a run of ``steps`` is cut into segments of
    at least :data:`SEGMENT_STEPS` (at most :data:`SEGMENTS`), each started from the end of the one
    before it in the previous pass until every start is that end to half the working precision. A
    model that forgets its start within a segment joins in a few passes of one segment's length; one
    that never forgets it (an integrator) needs one pass per segment, the steps of a sequential
    run. Runs that are differentiated (autograd or forward mode) are not segmented: their
    derivative would stop at the first guesses."""
    tensors = (x0, p.gamma, p.theta, p.theta_fixed, p.scale, record.t, record.external)
    if any((v.requires_grad and torch.is_grad_enabled()) or forward_ad.unpack_dual(v).tangent is not None
           for v in tensors):
        return 1
    return max(1, min(SEGMENTS, steps // SEGMENT_STEPS))


def _joined(joined: torch.Tensor, starts: torch.Tensor, span: torch.Tensor | None) -> bool:
    """Whether every segment starts (B, segments, S) where the segment before it ends, to half the
    working precision's digits of each row's state magnitude over the starts, or both are diverged
    (not finite, or beyond ``span``): by induction from the exact first segment, the run is then
    the sequential one."""
    inside = lambda v: torch.isfinite(v) & (True if span is None else v.abs() < span)
    a, b = inside(joined), inside(starts)
    magnitude = torch.maximum(torch.where(a, joined.abs(), 0.0), torch.where(b, starts.abs(), 0.0)).amax(-2, keepdim=True)
    close = a & b & ((joined - starts).abs() <= torch.finfo(joined.dtype).eps ** 0.5 * magnitude)
    return bool((close | (~a & ~b)).all())


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
