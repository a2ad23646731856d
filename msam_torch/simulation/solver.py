"""The one ``simulate()``: a model of Eq. 9 integrated over a record.

Fixed-step methods (``euler``, ``midpoint``, ``rk4``: torchdiffeq's tableaus, ``rk4`` its 3/8 rule)
run as an explicit Runge-Kutta loop whose step coefficients are tensors derived from the record's
time axis; the external signals are interpolated once at all stage times (sixths of a step), and
every expression of the model that reads no simulated state is tabulated there once
(:meth:`~msam_torch.simulation.ode.SystemModel.stage_rates`), so a stage evaluates only what depends on the states. In
forward mode (:mod:`.sensitivities`) the loop runs plain, once per distinct row, and the tangents
follow by the chain rule of the steps (:func:`_tangents`): a dual tensor carried through the loop
cost 3 to 5 times a plain one per operation, and torchdiffeq's fixed-grid steps, which multiply by
Python numbers, far more (about 0.7 ms per operation). Adaptive methods (``dopri5``, ...) are
torchdiffeq's, and fall back to ``rk4`` when their step underflows. Small batches run on one CPU
thread. A trajectory that leaves ``span`` is returned as NaN, so one diverging member neither
crashes nor stalls the batch: an adaptive method freezes it where it leaves (its step would
otherwise shrink for every member); the fixed-step loop, whose members never share a step, lets it
run on and marks it once at the end (a check per stage cost about a fifth of the loop). A long
fixed-step run that autograd does not differentiate is cut into segments integrated side by side,
each restarted from the end of the one before until they join (:func:`segments`): the loop's cost is
its per-stage overhead, nearly the same for one row as for hundreds.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import fields, replace

import torch
import torch.autograd.forward_ad as forward_ad

from msam_torch.simulation.grids import Grids
from msam_torch.simulation.ode import Parameters, SystemModel
from msam_torch.simulation.record import Record

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
TANGENT_ELEMENTS = 1 << 20  # state values per chunk of the tangents' one-step passes (:func:`_tangents`)


def simulate(model: SystemModel, record: Record, p: Parameters, x0: torch.Tensor, method: str = "rk4",
             substeps: int = 1, limits: torch.Tensor | None = None, span: torch.Tensor | None = None,
             step: float | None = None, rtol: float = 1e-6, atol: float = 1e-9, grids: Grids | None = None) -> torch.Tensor:
    """Integrate ``model`` from ``x0`` (B, S) over the record: states (B, N, S).

    ``step``: the fixed step (default: the sample period over ``substeps``); ``rtol``, ``atol``:
    adaptive methods. ``limits`` (2, S): a state's rate is zero while the state is at or beyond a
    limit and the rate points outwards (``simulation.saturation``). ``span`` (S,): a row whose
    state leaves ``|x| < span`` (or whose rate is not finite, under an adaptive method) is
    diverged and returned as NaN. ``grids``: fixed-step runs of rows already integrated are read
    from it, and every run kept there (:mod:`.grids`).
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
            states = _runge_kutta(model, p, record, x0, TABLEAUS[method], substeps, step, guarded, span, limits, grids)
        else:
            from torchdiffeq import odeint  # adaptive methods only: torchdiffeq imports scipy.integrate

            rhs = model.rhs(p, x0.dtype, x0.device)
            values = lambda t, x: model.values(t, x, record.at(t.reshape(1)).squeeze(-2))
            try:
                states = odeint(guarded(lambda t, x: rhs(values(t, x), x), span), x0, record.t, method=method,
                                rtol=rtol, atol=atol).movedim(0, -2)
            except AssertionError:  # torchdiffeq's step-size underflow: integrate with fixed steps instead
                return simulate(model, record, p, x0, "rk4", substeps, limits, span, step, grids=grids)
    if span is None:
        return states
    diverged = ~(states.abs() < span).all(-1).all(-1)  # (B,)
    return torch.where(diverged.view(-1, 1, 1), torch.full_like(states, torch.nan), states)


def _runge_kutta(model: SystemModel, p: Parameters, record: Record, x0: torch.Tensor, tableau, substeps: int,
                 step: float | None, guarded, span: torch.Tensor | None, limits: torch.Tensor | None = None,
                 grids: Grids | None = None) -> torch.Tensor:
    """The explicit Runge-Kutta loop on the grid ``t0 + i h`` (h = ``step`` or the sample period
    over ``substeps``), states at the record's times (interpolated linearly between grid points
    that miss them): (B, N, S). The external signals are interpolated at all stage times at once;
    a stage costs the model's per-stage operations. A stage at the end of a step reads the external
    signals just before it (their left limit): a held input that switches there is not read by
    the step it ends. A long run that is not differentiated runs in :func:`segments`; a run in
    forward mode is the plain run with its tangents from :func:`_tangents`. Rows kept in
    ``grids`` are not integrated again."""
    t = record.t
    times = forward_ad.unpack_dual(t).primal  # the plain run's times (a dual record's have a zero tangent)
    h_plain = (times[1] - times[0]) / substeps if step is None else torch.as_tensor(step, dtype=t.dtype, device=t.device)
    h = h_plain if _tangent(t) is None else forward_ad.make_dual(h_plain, torch.zeros_like(h_plain))
    steps = int(torch.ceil((times[-1] - times[0]) / h_plain - 1e-9))
    tensors = (x0, p.gamma, p.theta, p.theta_fixed, p.scale, record.t, record.external)
    reuse = grids is not None and record.external.dim() == 2 and not (torch.is_grad_enabled() and any(
        v.requires_grad for v in tensors))  # rows with signals of their own, or differentiated by autograd: run
    context = Grids.context(model, record, tableau, h_plain, steps, limits, span) if reuse else None

    def plain_grid(p, record, x0):  # (B, steps + 1, S), rows kept in ``grids`` read from it, the others kept there
        if not reuse:
            return _grid(model, p, record, x0, tableau, h_plain, steps, guarded, span, segments(steps, x0, p, record))
        keys = _keys(p, x0)
        hit, out = grids.take(context, keys)
        if not bool(hit.all()):
            run = torch.nonzero(~hit).flatten()
            fresh = _grid(model, _rows(p, run), record, x0[run], tableau, h_plain, steps, guarded, span,
                          segments(steps, x0[run], p, record))
            if out is not None:
                kept, out = out, fresh.new_empty((keys.shape[0],) + fresh.shape[1:])
                out[run], out[hit] = fresh, kept
            else:
                out = fresh
        grids.keep(context, keys, out)  # the latest batch holds every row it read
        return out

    if any(_tangent(v) is not None for v in tensors):
        plain = lambda v: None if v is None else forward_ad.unpack_dual(v).primal
        plain_p = Parameters(*(plain(getattr(p, f.name)) for f in fields(p)))
        plain_record = replace(record, t=plain(t), external=plain(record.external), pieces=plain(record.pieces))
        first, inverse = _distinct(plain_p, plain(x0), plain_record)
        u_p, u_record, u_x0 = _rows(plain_p, first), _rows(plain_record, first), plain(x0)[first]
        grid = plain_grid(u_p, u_record, u_x0)  # (U, steps + 1, S), one per distinct row
        grid = forward_ad.make_dual(grid[inverse], _tangents(model, p, record, x0, tableau, h, grid, first, inverse, guarded))
    else:
        grid = plain_grid(p, record, x0)
    position = (times - times[0]) / h_plain
    nearest = position.round()
    if bool(((position - nearest).abs() < 1e-6).all()):
        return grid[..., nearest.long().clamp(max=steps), :]
    k = position.floor().long().clamp(max=steps - 1)
    w = (position - k).unsqueeze(-1)
    return grid[..., k, :] * (1 - w) + grid[..., k + 1, :] * w


def _stepper(model: SystemModel, p: Parameters, record: Record, tableau, h, first: int, steps: int, parts: int,
             guarded):
    """``run(x, length)``: ``length`` steps of the tableau from x (..., [parts,] S), the grid
    (..., [parts,] length + 1, S); the steps are ``first`` to ``first + steps`` of the run, cut into
    ``parts`` consecutive segments side by side (``length`` = steps / parts)."""
    offsets, stages, weights = tableau
    t = record.t
    offset = torch.tensor(offsets, device=t.device)
    keys = (6 * torch.arange(first, first + steps, device=t.device).unsqueeze(-1) + offset).flatten()  # in the loop's order
    stage_times = t[0] + keys.to(t.dtype) * (h / 6)
    ends = (offset == 6).repeat(steps)  # a step's last stage reads its own input
    read_at = torch.where(ends, stage_times - h * READ_BEFORE, stage_times).clamp(max=t[-1])
    func = guarded(model.stage_rates(p, stage_times, record.at(read_at), parts))
    coefficients = [[h * a for a in row] for row in stages]
    weights = [(h * b, b) for b in weights]

    def run(x, length):
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

    return run


def _grid(model: SystemModel, p: Parameters, record: Record, x0: torch.Tensor, tableau, h, steps: int, guarded,
          span: torch.Tensor | None, parts: int) -> torch.Tensor:
    """The states on the step grid (B, steps + 1, S), in ``parts`` segments side by side."""
    length = -(-steps // parts)  # steps per segment; the last one's beyond the record read its end
    run = _stepper(model, p, record, tableau, h, 0, parts * length, parts, guarded)
    if parts == 1:
        return run(x0, length)  # (B, steps + 1, S)
    first = x0.unsqueeze(-2)  # every segment from the end of the one before it, until they join (Parareal without its coarse solver)
    starts = first.expand(x0.shape[:-1] + (parts, x0.shape[-1]))  # the first guess of every segment's start
    for _ in range(parts):  # after k passes the first k segments are exact: at most ``parts`` passes
        grid = run(starts, length)  # (B, parts, length + 1, S)
        joined = torch.cat([first, grid[..., :-1, -1, :]], -2)
        if _joined(joined, starts, span):
            break
        starts = joined
    return torch.cat([grid[..., :-1, :].flatten(-3, -2), grid[..., -1:, -1, :]], -2)[..., :steps + 1, :]


def _tangents(model: SystemModel, p: Parameters, record: Record, x0: torch.Tensor, tableau, h, grid: torch.Tensor,
              first: torch.Tensor, inverse: torch.Tensor, guarded) -> torch.Tensor:
    """Forward mode along the plain run's step grid (U, steps + 1, S) of the distinct rows (``first``
    of each, row b's at ``inverse[b]``): the tangent (B, steps + 1, S) of every row's grid states by
    the chain rule of the steps, ``x'_{n+1} = A_n x'_n + b_n``. ``A_n`` (the step's Jacobian in the
    state, S directions per distinct row) and ``b_n`` (its derivative along the row's parameter
    tangent) come from forward-mode passes of one step over a chunk of grid states at once, so a
    stage's operations run once per chunk rather than once per step; the recurrence is solved by
    a scan of the steps' compositions in log2(steps) products."""
    u, steps, s = grid.shape[0], grid.shape[-2] - 1, grid.shape[-1]
    b = inverse.shape[0]

    def constant(v):  # a parameter's primal with a zero tangent (choices as they are)
        if v.dtype == torch.long:
            return v
        v = forward_ad.unpack_dual(v).primal.contiguous()
        return forward_ad.make_dual(v, torch.zeros_like(v))

    # A_n: the distinct rows, each repeated per state direction, the parameters' tangents zero
    a_params = Parameters(*(constant(getattr(p, f.name)[first].repeat_interleave(s, 0)) for f in fields(p)))
    basis = torch.eye(s, dtype=grid.dtype, device=grid.device)
    jacobian = _one_step(model, a_params, _rows(record, first, s), tableau, h, guarded, grid[:, :-1].repeat_interleave(s, 0),
                         lambda n: basis.view(1, s, 1, s).expand(u, s, n, s).flatten(0, 1))
    jacobian = jacobian.unflatten(0, (u, s)).permute(0, 2, 3, 1)  # (U, steps, S out, S in)
    start = _tangent(x0)
    start = torch.zeros(b, s, dtype=grid.dtype, device=grid.device) if start is None else start.expand(b, s)
    # b_n: the rows whose parameters have a tangent (zero for the others), the state's zero
    moving = torch.zeros(b, dtype=torch.bool, device=grid.device)
    for f in fields(p):
        tangent = _tangent(getattr(p, f.name))
        if tangent is not None:
            moving |= (tangent != 0).flatten(1).any(-1).expand(b)
    live = torch.nonzero(moving | (start != 0).any(-1)).flatten()  # the others' tangent is zero throughout
    tangents = torch.zeros(b, steps + 1, s, dtype=grid.dtype, device=grid.device)
    tangents[:, 0] = start
    if not live.numel():
        return tangents
    forcing = torch.zeros(live.shape[0], steps, s, dtype=grid.dtype, device=grid.device)
    forced = torch.nonzero(moving[live]).flatten()
    if forced.numel():
        rows = live[forced]
        own = lambda v: v if v.dtype == torch.long or _tangent(v) is not None else constant(v)
        b_params = Parameters(*(own(getattr(p, f.name).expand(b, -1))[rows] for f in fields(p)))
        forcing[forced] = _one_step(model, b_params, _rows(record, rows), tableau, h, guarded, grid[inverse[rows], :-1],
                                    lambda n: torch.zeros(rows.shape[0], n, s, dtype=grid.dtype, device=grid.device))
    jacobian, start = jacobian[inverse[live]], start[live]
    shift = 1
    while shift < steps:  # prefix compositions of the steps' affine maps (a Hillis-Steele scan): step k from the start
        jacobian, forcing = (torch.cat([jacobian[:, :shift], _product(jacobian[:, shift:], jacobian[:, :-shift])], 1),
                             torch.cat([forcing[:, :shift], _product(jacobian[:, shift:], forcing[:, :-shift].unsqueeze(-1))
                                        .squeeze(-1) + forcing[:, shift:]], 1))
        shift *= 2
    tangents[live, 1:] = _product(jacobian, start.view(-1, 1, s, 1)).squeeze(-1) + forcing  # (live, steps, S)
    return tangents


def _product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b``; of 1 x 1 matrices elementwise (the same numbers, a tenth of the time)."""
    return a * b if a.shape[-1] == 1 and a.shape[-2] == 1 else a @ b


def _one_step(model: SystemModel, p: Parameters, record: Record, tableau, h, guarded, x: torch.Tensor,
              tangent) -> torch.Tensor:
    """The tangent of one step from each of the states ``x`` (R, steps, S) with the tangents
    ``tangent(n)`` (R, n, S) of a chunk of n of them: (R, steps, S), in chunks of at most
    :data:`TANGENT_ELEMENTS` state values."""
    rows, steps, s = x.shape
    chunk = max(1, TANGENT_ELEMENTS // (rows * s))
    out = []
    for first in range(0, steps, chunk):
        n = min(chunk, steps - first)
        run = _stepper(model, p, record, tableau, h, first, n, n, guarded)
        start = forward_ad.make_dual(x[:, first:first + n].contiguous(), tangent(n).contiguous())
        moved = run(start, 1)[..., 1, :] if n > 1 else run(start[:, 0], 1)[..., 1:, :]  # one segment has no segment axis
        out.append(forward_ad.unpack_dual(moved).tangent)
    return torch.cat(out, 1)


def _keys(p: Parameters, x0: torch.Tensor) -> torch.Tensor:
    """What a plain run of each row depends on (B, D): its parameters and start."""
    return torch.cat([p.gamma, p.choice.to(p.gamma.dtype), p.theta, p.theta_fixed, p.scale, x0], -1)


def _distinct(p: Parameters, x0: torch.Tensor, record: Record) -> tuple[torch.Tensor, torch.Tensor]:
    """The first of each set of rows with the same parameters and start (U,) and every row's set
    (B,): rows that differ only in their tangents (the sensitivities' directions) share one plain
    run. Rows with signals of their own, or a value that is not a number, are all distinct."""
    keys = _keys(p, x0)
    rows = torch.arange(keys.shape[0], device=keys.device)
    if record.external.dim() == 3 or bool(torch.isnan(keys).any()):
        return rows, rows
    _, inverse = torch.unique(keys, dim=0, return_inverse=True)
    first = torch.full((int(inverse.max()) + 1,), keys.shape[0], device=keys.device).scatter_reduce(0, inverse, rows, "amin")
    return first, inverse


def _rows(value, index: torch.Tensor, repeats: int = 1):
    """Parameters or a record (its per-row signals) at the rows ``index``, each ``repeats`` times."""
    take = lambda v: None if v is None else v[index].repeat_interleave(repeats, 0)
    if isinstance(value, Parameters):
        return Parameters(*(take(getattr(value, f.name)) for f in fields(value)))
    if value.external.dim() != 3:
        return value
    return replace(value, external=take(value.external), pieces=value.pieces if value.pieces is None or value.pieces.dim() < 4
                   else take(value.pieces))


def _tangent(v: torch.Tensor | None) -> torch.Tensor | None:
    return None if v is None else forward_ad.unpack_dual(v).tangent


def segments(steps: int, x0: torch.Tensor, p: Parameters, record: Record) -> int:
    """How many segments a fixed-step run integrates side by side: a Python loop of tiny operations
    costs about the same for one row as for hundreds, so a run of ``steps`` is cut into segments of
    at least :data:`SEGMENT_STEPS` (at most :data:`SEGMENTS`), each started from the end of the one
    before it in the previous pass until every start is that end to half the working precision. A
    model that forgets its start within a segment joins in a few passes of one segment's length; one
    that never forgets it (an integrator) needs one pass per segment, the steps of a sequential
    run. A run differentiated by autograd is not segmented: its derivative would stop at the
    first guesses (in forward mode the plain run is segmented, its tangents follow the joined grid:
    :func:`_tangents`)."""
    tensors = (x0, p.gamma, p.theta, p.theta_fixed, p.scale, record.t, record.external)
    if torch.is_grad_enabled() and any(v.requires_grad for v in tensors):
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
