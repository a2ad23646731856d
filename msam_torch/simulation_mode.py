"""Simulation-based evaluation of candidates: the alternative of the paper's section 2.

Algebraic evaluation (Eq. 6) needs every state the model reads, estimated from measurements. When
a state is not measured (the upper tank of the cascaded tanks) a candidate can only be judged by
simulating it: the candidate's states are integrated with a fixed-step torchdiffeq solver under the
measured inputs, and the simulated *outputs* (measured states, ``adaptation.simulation.output``)
are compared with the data. The same round robin and refinement (Algorithm 1, :class:`Trainer`)
run on the simulated output with :class:`SimulationEvaluator`:

- structural sensitivities by finite differences of the simulated output (Eq. 16), scaled by dM
  (Eq. 15) computed from the simulated parameter sensitivities, or by ``dgamma``;
- theta (``adaptation.theta: varpro``) and the initial states (``simulation.initial: estimate``) are
  extra least-squares parameters, stepped jointly with the exponents (Gauss-Newton on the stacked
  Jacobian; for the exponents this equals the step projected off theta and the initial states);
- a short Levenberg-Marquardt fit of theta and the initial states of the unadjusted starting model
  comes first (the theta-retuned starting model every result is compared with);
- ``normalize: rms`` divides each adjustment function by its RMS along that starting simulation.

Batches are flattened into one simulation: trials x candidates x finite-difference perturbations.
The solver is torchdiffeq's fixed-grid ``rk4`` (or ``midpoint``, ``euler``), which torch.func
transforms pass through (the tests check ``jacfwd`` against the finite differences).

Shapes: ``T`` trials, ``C`` candidates, ``N`` samples, ``O`` outputs, ``S`` simulated states,
``Qa`` adjustable and ``P`` fixed components, ``G`` distinct adjustment functions, ``Z`` = Qa + P + S
least-squares parameters (theta, theta_fixed, initial states).
"""
from __future__ import annotations

import itertools
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torchdiffeq import odeint

from .candidates import FLOOR, power
from .config import Config, DataConfig, SimulationConfig
from .data import column, read_frame, select_range, simulated_measurements, time_axis, check_time
from .derivatives import estimate
from .errors import ConfigError
from .fitness import correlation, fitness, sum_abs_error
from .sensitivity import condition_number, structural_sensitivities
from .spec import Equation, ModelSpec, derivative_name, split_derivative
from .step import Evaluation, State, StepOptions, StepResult, advance, lstsq, step_size
from .trainer import measures

PREFIT_DAMPING = (0.0, 1e-4, 1e-2, 1.0)  # Levenberg-Marquardt dampings tried at once
SERIAL_ELEMENTS = 32768  # batches of fewer state values are simulated on one thread (torch's grain size)


@dataclass(frozen=True)
class SystemModel:
    """State equations (Eq. 9) as an ODE right-hand side over the simulated states.

    A simulated state's derivative is either an equation's target or another simulated state
    (``x_dot`` for ``x``). ``external`` signals (inputs, and states read from the data in
    ``separate`` coupling) are interpolated from the record.
    """

    states: tuple[str, ...]
    equations: tuple[Equation, ...]
    external: tuple[str, ...]
    source: tuple[int, ...]  # per state: index into cat(states, equation rates)
    adjustable: tuple[tuple[int, int], ...]  # (equation, component) of every adjustable component
    fixed: tuple[tuple[int, int], ...]
    functions: tuple  # distinct adjustment Expressions (G)
    allowed: tuple[tuple[int, ...], ...]  # per adjustable component: indices into functions

    @classmethod
    def build(cls, spec: ModelSpec, equations: tuple[Equation, ...], external: tuple[str, ...]) -> "SystemModel":
        targets = {eq.target: e for e, eq in enumerate(equations)}
        bases = {split_derivative(eq.target)[0] for eq in equations}
        states = tuple(s for s in spec.states if split_derivative(s)[0] in bases)
        source = []
        for s in states:
            base, order = split_derivative(s)
            rate = derivative_name(base, order + 1)
            if rate in targets:
                source.append(len(states) + targets[rate])
            elif rate in states:
                source.append(states.index(rate))
            else:
                raise ConfigError("model.states", f"state {s!r} can be simulated only if {rate!r} is a state or "
                                  "the target of an equation")
        readable = set(states) | set(external) | {"t"}
        for e, eq in enumerate(equations):
            unknown = sorted(eq.signals - {eq.target} - readable)
            if unknown:
                raise ConfigError(f"model.equations[{spec.equations.index(eq)}]", f"simulation cannot give {unknown}: "
                                  "only simulated states, inputs, measured states and t can be read")
        texts, functions, allowed = [], [], []
        for e, eq in enumerate(equations):
            indices = []
            for f in eq.adjustments:
                if f.text not in texts:
                    texts.append(f.text)
                    functions.append(f)
                indices.append(texts.index(f.text))
            allowed.extend(tuple(indices[j] for j in eq.allowed(i)) for i in eq.adjustable)
        adjustable = tuple((e, i) for e, eq in enumerate(equations) for i in eq.adjustable)
        fixed = tuple((e, i) for e, eq in enumerate(equations) for i in eq.fixed)
        return cls(states, tuple(equations), tuple(external), tuple(source), adjustable, fixed, tuple(functions),
                   tuple(allowed))

    def choices(self, device=None) -> torch.Tensor:
        """Every candidate: one allowed function per adjustable component, (C, Qa)."""
        return torch.tensor(list(itertools.product(*self.allowed)), dtype=torch.long, device=device)

    @property
    def unadjusted(self) -> int:
        """The function index that leaves a component as it is (the starting model)."""
        return len(self.functions)

    def values(self, t, x: torch.Tensor, external: torch.Tensor) -> dict:
        """Signals at time ``t`` from states ``x`` (..., S) and external values (..., E)."""
        values = {"t": t}
        values.update(zip(self.states, x.unbind(-1)))
        values.update(zip(self.external, external.unbind(-1)))
        return values

    def functions_at(self, values: dict, shape) -> torch.Tensor:
        """Adjustment functions (..., G)."""
        return _stack([f(values) for f in self.functions], shape, values["t"].dtype)

    def rhs(self, p: "Parameters", dtype, device):
        """``rates(values, x)``: ``d x / dt`` (B, S) from the equations ``sum theta M f^gamma``
        (Eq. 9) and the kinematic states, with the constants of ``p`` bound once."""
        def assign(components):
            matrix = torch.zeros(len(components), len(self.equations), dtype=dtype, device=device)
            for k, (e, _) in enumerate(components):
                matrix[k, e] = 1.0
            return matrix

        inverse_scale = 1.0 / p.scale
        signed = [not f.is_magnitude for f in self.functions]
        magnitude = torch.tensor([not v for v in signed], device=device)
        adjustable_terms = [self.equations[e].components[i].term for e, i in self.adjustable]
        fixed_terms = [self.equations[e].components[i].term for e, i in self.fixed]
        assign_adjustable, assign_fixed = assign(self.adjustable), assign(self.fixed)
        source = torch.tensor(self.source, device=device)
        pad = torch.zeros(p.gamma.shape[:-1] + (1,), dtype=dtype, device=device)

        def rates(values: dict, x: torch.Tensor) -> torch.Tensor:
            shape = x.shape[:-1]
            cache: dict = {}
            f = _stack([_cached(g, values, shape, cache) for g in self.functions], shape, dtype) * inverse_scale
            log_f = torch.cat([torch.log(f.abs().clamp_min(FLOOR)), pad], -1)
            factor = power(torch.gather(log_f, -1, p.choice), p.gamma)
            if any(signed):
                sign = torch.cat([torch.where(magnitude, torch.ones_like(f), torch.sign(f)), pad + 1.0], -1)
                factor = factor * torch.gather(sign, -1, p.choice)
            terms = _stack([_cached(m, values, shape, cache) for m in adjustable_terms], shape, dtype)
            rates = (terms * factor * p.theta) @ assign_adjustable
            if fixed_terms:
                fixed = _stack([_cached(m, values, shape, cache) for m in fixed_terms], shape, dtype)
                rates = rates + (fixed * p.theta_fixed) @ assign_fixed
            return torch.index_select(torch.cat([x, rates], -1), -1, source)

        return rates


def _cached(expression, values: dict, shape, cache: dict):
    """Evaluate each distinct expression text once per call."""
    if expression.text not in cache:
        cache[expression.text] = expression(values)
    return cache[expression.text]


def _stack(items: list, shape, dtype) -> torch.Tensor:
    """Stack values that may be numbers or tensors broadcastable to ``shape``: (*shape, K)."""
    tensors = [v if torch.is_tensor(v) and v.shape == shape else torch.as_tensor(v, dtype=dtype).expand(shape)
               for v in items]
    return torch.stack(tensors, -1)


@dataclass(frozen=True)
class Parameters:
    """Per simulated trajectory (B rows): exponents, choices, theta, fixed theta, function scale."""

    gamma: torch.Tensor  # (B, Qa)
    choice: torch.Tensor  # (B, Qa) long
    theta: torch.Tensor  # (B, Qa)
    theta_fixed: torch.Tensor  # (B, P)
    scale: torch.Tensor  # (B, G)


@dataclass(frozen=True)
class Record:
    """A measured record on a uniform grid: time, external signals, measured outputs."""

    t: torch.Tensor  # (N,)
    external: torch.Tensor  # (N, E) inputs and states read from the data
    outputs: torch.Tensor  # (O, N) measured outputs
    guess: torch.Tensor  # (S,) initial states: measured, estimated from derivatives, or configured
    hold: str = "linear"
    pieces: torch.Tensor | None = None  # (N-1, 4, E) cubic interpolating spline of ``external`` (hold "cubic")

    @classmethod
    def build(cls, t: torch.Tensor, external: torch.Tensor, outputs: torch.Tensor, guess: torch.Tensor,
              hold: str = "linear") -> "Record":
        """A record; ``hold: cubic`` fits the not-a-knot cubic spline through the external samples
        (the band-limited signal between samples, which linear interpolation attenuates near the
        Nyquist frequency)."""
        pieces = None
        if hold == "cubic" and external.shape[-1]:
            from scipy.interpolate import CubicSpline

            spline = CubicSpline(t.cpu().numpy(), external.cpu().numpy(), axis=0)
            pieces = torch.as_tensor(spline.c, dtype=external.dtype, device=external.device).movedim(0, 1)
        return cls(t, external, outputs, guess, hold, pieces)

    def to(self, device) -> "Record":
        move = lambda v: None if v is None else v.to(device)
        return Record(move(self.t), move(self.external), move(self.outputs), move(self.guess), self.hold, move(self.pieces))

    def at(self, t: torch.Tensor) -> torch.Tensor:
        """External signals at times ``t`` (...) -> (..., E): linear interpolation, zero-order hold or
        cubic spline."""
        n = self.t.shape[0]
        step = self.t[1] - self.t[0]
        position = (t - self.t[0]) / step
        if self.hold == "zoh":
            return self.external[torch.floor(position + 1e-9).long().clamp(0, n - 1)]
        k = torch.floor(position).long().clamp(0, n - 2)
        if self.pieces is not None:
            s, c = ((position - k) * step).unsqueeze(-1), self.pieces[k].movedim(-2, 0)
            return ((c[0] * s + c[1]) * s + c[2]) * s + c[3]
        w = (position - k).clamp(0.0, 1.0).unsqueeze(-1)
        return self.external[k] * (1 - w) + self.external[k + 1] * w


def simulate(model: SystemModel, record: Record, p: Parameters, x0: torch.Tensor, method: str = "rk4",
             substeps: int = 1, limits: torch.Tensor | None = None) -> torch.Tensor:
    """Integrate ``model`` from ``x0`` (B, S) over the record with a fixed-step torchdiffeq solver:
    states (B, N, S). External signals at the solver's stage times (sixths of a step: the stages of
    rk4 (3/8 rule), midpoint and euler) are interpolated at once beforehand and looked up.
    ``limits`` (2, S): a state's rate is zero while the state is at or beyond a limit and the rate
    points outwards (``simulation.saturation``)."""
    rates = model.rhs(p, x0.dtype, x0.device)
    step = float(record.t[1] - record.t[0]) / substeps
    t0 = float(record.t[0])
    sixths = 6 * substeps * (record.t.shape[0] - 1) + 1
    table = record.at(record.t[0] + torch.arange(sixths, dtype=record.t.dtype, device=record.t.device) * (step / 6))
    columns = table.unbind(-1)

    def func(t, x):
        key = min(max(round((float(t) - t0) / step * 6), 0), sixths - 1)
        values = {"t": t, **dict(zip(model.states, x.unbind(-1))), **{name: c[key] for name, c in zip(model.external, columns)}}
        rate = rates(values, x)
        if limits is None:
            return rate
        held = ((x >= limits[1]) & (rate > 0)) | ((x <= limits[0]) & (rate < 0))
        return torch.where(held, torch.zeros_like(rate), rate)

    with _single_thread(x0.numel() < SERIAL_ELEMENTS and x0.device.type == "cpu"):
        trajectory = odeint(func, x0, record.t, method=method, options={"step_size": step})
    return trajectory.movedim(0, -2)


@contextmanager
def _single_thread(serial: bool):
    """Run a fixed-step simulation of a small batch on one CPU thread: its thousands of tiny
    per-stage operations gain nothing from intra-op threads and lose much to their
    synchronisation (tenfold when the other cores are busy). The thread count is restored."""
    threads = torch.get_num_threads()
    if serial and threads > 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


@dataclass(frozen=True)
class SimulationData:
    """What the evaluator needs: the model, the training record, solver options and the
    parameters of the starting point (theta are the trainer's; ``initial`` (T, S) and ``scale``
    (T, G) are the simulation's own)."""

    model: SystemModel
    record: Record
    outputs: tuple[int, ...]  # indices of the output states
    initial: torch.Tensor  # (T, S)
    scale: torch.Tensor  # (T, G)
    free: torch.Tensor  # (Z,) bool: which of theta, theta_fixed, initial are estimated
    method: str = "rk4"
    substeps: int = 1
    relative_step: float = 1e-6
    refit_steps: int = 0  # Levenberg-Marquardt steps on theta and initial states before every exponent step
    limits: torch.Tensor | None = None  # (2, S) range of the simulated states (``simulation.saturation``)

    @property
    def y(self) -> torch.Tensor:
        """Measured outputs, flattened (1, O N)."""
        return self.record.outputs.reshape(1, -1)

    def select(self, choices: torch.Tensor) -> "SimulationSelection":
        return SimulationSelection(self, choices)

    def output(self, gamma, choice, theta, theta_fixed, initial) -> torch.Tensor:
        """Simulated outputs for any leading batch shape: (..., O N)."""
        batch = gamma.shape[:-1]
        flat = lambda v: v.expand(batch + v.shape[-1:]).flatten(0, len(batch) - 1)
        t = self.scale.shape[0]
        scale = self.scale.view((t,) + (1,) * (len(batch) - 1) + self.scale.shape[-1:]) if len(batch) > 1 else self.scale
        p = Parameters(flat(gamma), flat(choice), flat(theta), flat(theta_fixed), flat(scale))
        states = simulate(self.model, self.record, p, flat(initial), self.method, self.substeps, self.limits)
        if self.limits is not None:  # a fixed step may overshoot a limit by a fraction of a step
            states = torch.clamp(states, self.limits[0], self.limits[1])
        out = states[..., list(self.outputs)].movedim(-1, -2).reshape(states.shape[0], -1)
        return out.reshape(batch + out.shape[-1:])


@dataclass(frozen=True)
class SimulationSelection:
    data: SimulationData
    choices: torch.Tensor  # (C, Qa) or (T, C, Qa)

    @property
    def y(self) -> torch.Tensor:
        return self.data.y.unsqueeze(1)  # (1, 1, O N)

    def choice(self, state: State) -> torch.Tensor:
        return self.choices.expand(state.gamma.shape)


def _initial(selection: SimulationSelection, state: State) -> torch.Tensor:
    if state.initial is not None:
        return state.initial
    initial = selection.data.initial
    return initial.unsqueeze(1).expand(state.gamma.shape[:2] + initial.shape[-1:])


def _packed(state: State, initial: torch.Tensor) -> torch.Tensor:
    """The least-squares parameters z = [theta, theta_fixed, initial] (..., Z)."""
    return torch.cat([state.theta, state.theta_fixed, initial], -1)


def _unpacked(z: torch.Tensor, q: int, p: int):
    return z[..., :q], z[..., q: q + p], z[..., q + p:]


class SimulationEvaluator:
    """Evaluator for :class:`~msam_torch.trainer.Trainer`: candidates judged by their simulation."""

    @staticmethod
    def evaluate(selection: SimulationSelection, state: State, options: StepOptions) -> Evaluation:
        initial = _initial(selection, state)
        yhat = selection.data.output(state.gamma, selection.choice(state), state.theta, state.theta_fixed, initial)
        y = selection.y
        score = torch.where(state.diverged, torch.full_like(state.diverged, -torch.inf, dtype=yhat.dtype), fitness(y, yhat))
        return Evaluation(yhat.new_zeros(yhat.shape[:2] + (0, 0)), yhat, state.theta, state.theta_fixed, score,
                          sum_abs_error(y, yhat), correlation(yhat, y), initial)

    @staticmethod
    def step(selection: SimulationSelection, state: State, current: Evaluation, options: StepOptions,
             conditions: bool = True) -> StepResult:
        """Eq. 15-18 on the simulated output, theta and initial states stepped jointly."""
        data = selection.data
        q, p = state.theta.shape[-1], state.theta_fixed.shape[-1]
        initial = _initial(selection, state)
        z = _packed(state, initial)
        free = data.free.clone()
        if options.theta == "fixed":
            free[: q + p] = False
        if data.refit_steps:  # theta and initial states refitted for the current exponents (variable projection by iteration)
            z, yhat = fit_parameters(data, selection.choice(state), state.gamma, z, free, data.refit_steps)
            y = selection.y
            current = replace(current, yhat=yhat, fitness=torch.where(state.diverged, current.fitness, fitness(y, yhat)))
        jac = jacobians(data, selection.choice(state), state.gamma, z, options.dgamma)
        blown = ~_usable(current.yhat).all(-1, keepdim=True)  # (T, C, 1): its simulation left the float range
        eps = torch.where(blown, torch.zeros_like(current.yhat), selection.y - current.yhat)
        phi_scaled = structural_sensitivities(jac.gamma, jac.dm)
        phi_unscaled = structural_sensitivities(jac.gamma, torch.full_like(jac.dm, options.dgamma))
        phi_gamma = phi_scaled if options.scaling == "dm" else phi_unscaled
        phi = torch.where(blown.unsqueeze(-1), 0.0, torch.cat([phi_gamma, jac.z[..., free]], -1))
        delta = lstsq(phi, eps, options.damping, options.rcond)
        delta_gamma, delta_z = delta[..., :q], torch.zeros_like(z)
        delta_z[..., free] = delta[..., q:]

        def trial_fitness(mu, among):  # every candidate simulated, whether among or not
            gamma, trial_z = state.gamma + mu * delta_gamma, z + mu * delta_z
            return fitness(selection.y, data.output(gamma, selection.choice(state), *_unpacked(trial_z, q, p)))

        mu = step_size(current.fitness, (phi @ delta.unsqueeze(-1)).squeeze(-1), eps, options, trial_fitness)
        gamma, diverged = advance(state.gamma, mu, delta_gamma, state.diverged, current.fitness, options)
        new_z = torch.where(diverged.unsqueeze(-1), z, z + mu.unsqueeze(-1) * delta_z)
        theta, theta_fixed, new_initial = _unpacked(new_z, q, p)
        new_state = State(gamma, theta, theta_fixed, diverged, new_initial)
        cond_scaled, cond_unscaled = (condition_number(phi_scaled), condition_number(phi_unscaled)) if conditions else (None, None)
        return StepResult(new_state, mu, delta_gamma, jac.dm, cond_scaled, cond_unscaled)

    @staticmethod
    def starting_measures(data: SimulationData, theta: torch.Tensor, theta_fixed: torch.Tensor) -> dict:
        """Measures of the unadjusted starting model (theta as given, initial states of ``data``)."""
        yhat = data.output(torch.zeros_like(theta), torch.full_like(theta, data.model.unadjusted, dtype=torch.long),
                           theta, theta_fixed, data.initial)
        return measures(data.y, yhat)


@dataclass(frozen=True)
class Jacobians:
    gamma: torch.Tensor  # (T, C, N, Qa) yhat(gamma + dgamma e_i) - yhat (the numerator of Eq. 16)
    z: torch.Tensor  # (T, C, N, Z) d yhat / d z (zero columns for parameters that are not free)
    dm: torch.Tensor  # (T, C, Qa) Eq. 15
    base: torch.Tensor  # (T, C, N) the output at the base point


def _usable(values: torch.Tensor) -> torch.Tensor:
    """Finite and far from overflow (squares and sums of it stay finite)."""
    return torch.isfinite(values) & (values.abs() < 1e100)


def _steps(z: torch.Tensor, relative: float) -> torch.Tensor:
    return relative * torch.where(z.abs() > 0, z.abs(), torch.ones_like(z))


def jacobians(data: SimulationData, choice, gamma, z, dgamma: float, structural: bool = True) -> Jacobians:
    """Finite-difference sensitivities of the simulated output, all in one batched simulation.

    Rows per candidate: the base point, ``gamma_i + dgamma``, ``z_j + h_j`` for the adjustable
    theta and every free parameter, and ``(gamma_i + dgamma, theta_j + h_j)`` for dM (Eq. 15),
    whose parameter sensitivities are those to the adjustable components' theta (design.md 2.2).
    With ``structural=False`` only the base point and the free parameters are simulated.
    """
    q = gamma.shape[-1] if structural else 0
    zq = z.shape[-1]
    p = zq - gamma.shape[-1] - data.initial.shape[-1]
    perturb = data.free.clone()
    perturb[:q] = True
    columns = torch.nonzero(perturb).flatten().tolist()
    h = _steps(z, data.relative_step)
    eye_q, eye_z = torch.eye(gamma.shape[-1], dtype=z.dtype, device=z.device), torch.eye(zq, dtype=z.dtype, device=z.device)
    rows_gamma = [gamma] + [gamma + dgamma * eye_q[i] for i in range(q)] + [gamma] * len(columns) \
        + [gamma + dgamma * eye_q[i] for i in range(q) for _ in range(q)]
    rows_z = [z] * (1 + q) + [z + h * eye_z[j] for j in columns] + [z + h * eye_z[j] for _ in range(q) for j in range(q)]
    gammas, zs = torch.stack(rows_gamma, -2), torch.stack(rows_z, -2)  # (T, C, K, .)
    theta, theta_fixed, initial = _unpacked(zs, gamma.shape[-1], p)
    out = data.output(gammas, choice.unsqueeze(-2).expand(gammas.shape), theta, theta_fixed, initial)
    base = out[..., 0, :]
    out = torch.where(_usable(out), out, torch.zeros_like(out))
    k = 1 + q
    delta_gamma = (out[..., 1:k, :] - out[..., :1, :]).mT
    jz = torch.zeros(z.shape[:-1] + (base.shape[-1], zq), dtype=z.dtype, device=z.device)
    jz[..., columns] = ((out[..., k: k + len(columns), :] - out[..., :1, :]) / h[..., columns].unsqueeze(-1)).mT
    k += len(columns)
    if not structural:
        return Jacobians(delta_gamma, jz, torch.zeros_like(gamma), base)
    s = jz[..., :q]  # (T, C, N, Qa) sensitivity to the adjustable theta at Gamma
    perturbed_base = out[..., 1: 1 + q, :]  # (T, C, Qa, N)
    s_perturbed = (out[..., k:, :].unflatten(-2, (q, q)) - perturbed_base.unsqueeze(-2)) / h[..., :q].unsqueeze(-2).unsqueeze(-1)
    numerator = torch.linalg.vector_norm(s_perturbed.mT - s.unsqueeze(-3), dim=-1).sum(-1)
    denominator = torch.linalg.vector_norm(s, dim=-1).sum(-1, keepdim=True)
    dm = numerator / denominator.clamp_min(torch.finfo(z.dtype).tiny)
    return Jacobians(delta_gamma, jz, dm, base)


def fit_parameters(data: SimulationData, choice, gamma, z, free: torch.Tensor, steps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Levenberg-Marquardt on the ``free`` entries of z (T, C, Z) for fixed exponents (T, C, Qa).

    Each step tries the dampings of :data:`PREFIT_DAMPING` together with their Jacobians in one
    batched simulation and keeps, per candidate, the best that lowers the sum of squares. Returns z
    and the simulated output (T, C, M).
    """
    q = gamma.shape[-1]
    p = z.shape[-1] - q - data.initial.shape[-1]
    if steps == 0 or not bool(free.any()):
        return z, data.output(gamma, choice, *_unpacked(z, q, p))
    fixed_free = replace(data, free=free)
    y = data.y.unsqueeze(1)
    n = len(PREFIT_DAMPING)

    def linearise(points):  # (T, C, L, Z) -> output (T, C, L, M), Jacobian (T, C, L, M, Zf)
        g = gamma.unsqueeze(-2).expand(points.shape[:-1] + (q,))
        c = choice.unsqueeze(-2).expand(points.shape[:-1] + (q,))
        jac = jacobians(fixed_free, c.flatten(1, 2), g.flatten(1, 2), points.flatten(1, 2), 1.0, structural=False)
        return jac.base.unflatten(1, points.shape[1:3]), jac.z[..., free].unflatten(1, points.shape[1:3])

    out, jz = (v.squeeze(2) for v in linearise(z.unsqueeze(-2)))
    sse = torch.where(_usable(out), (y - out) ** 2, torch.inf).sum(-1)
    for _ in range(steps):
        eps = torch.where(_usable(out), y - out, torch.zeros_like(out))
        deltas = torch.stack([lstsq(jz, eps, damping) for damping in PREFIT_DAMPING], -2)  # (T, C, L, Zf)
        trial = z.unsqueeze(-2).repeat_interleave(n, -2)
        trial[..., free] = trial[..., free] + deltas
        out_t, jz_t = linearise(trial)
        sse_t = torch.where(_usable(out_t), (y.unsqueeze(-2) - out_t) ** 2, torch.inf).sum(-1)  # (T, C, L)
        best_sse, best = sse_t.min(-1)
        better = best_sse < sse
        pick = lambda v: v.gather(2, best.view(best.shape + (1,) * (v.dim() - 2)).expand(v.shape[:2] + (1,) + v.shape[3:])).squeeze(2)
        keep = lambda new, old: torch.where(better.view(better.shape + (1,) * (old.dim() - 2)), new, old)
        z, out, jz, sse = keep(pick(trial), z), keep(pick(out_t), out), keep(pick(jz_t), jz), torch.where(better, best_sse, sse)
    return z, out


# --- from a config: records, the starting fit, Algorithm 1, results, free-run validation -------------------------

def load_records(config: Config, spec: ModelSpec, model: SystemModel, outputs: tuple[str, ...], base_dir: Path,
                 dtype=torch.float64) -> tuple[Record, Record | None]:
    """Training and (if configured) validation records for ``model``."""
    data, sim = config.data, config.adaptation.simulation
    names = list(model.external) + list(outputs)
    if data.system is not None:
        simulated, measured = simulated_measurements(data)
        missing = [n for n in names if n not in measured]
        if missing:
            raise ConfigError("adaptation.simulation.output", f"system {data.system!r} does not measure {missing} "
                              f"(it measures {sorted(measured)})")
        return _record(simulated["t"], measured, model, outputs, data, sim, dtype), None
    if data.file is None:
        raise ConfigError("data", "give exactly one of 'system' (simulated) or 'file' (measured)")
    frame, source = read_frame(base_dir / data.file)

    def record(part, source, key):
        measured = {name: column(part, col, source, f"data.columns.{name}") for name, col in data.columns.items()}
        t, measured, _ = check_time(part, time_axis(part, data, source), measured, source, data, False, {})
        missing = [n for n in names if n not in measured]
        if missing:
            raise ConfigError("data.columns", f"simulation needs a column for {missing} ({key})")
        return _record(t, measured, model, outputs, data, sim, dtype)

    train = record(select_range(frame, data.train, data, source, "data.train"), source, "data.train")
    validation = None
    if data.validation_file is not None:
        frame, source = read_frame(base_dir / data.validation_file)
        validation = record(frame, source, "data.validation_file")
    elif data.validation is not None:
        validation = record(select_range(frame, data.validation, data, source, "data.validation"), source, "data.validation")
    return train, validation


def _record(t, measured: dict, model: SystemModel, outputs, data: DataConfig, sim: SimulationConfig, dtype) -> Record:
    """A :class:`Record`; initial-state guesses from the data, derivative estimates or ``initial_guess``."""
    t = np.asarray(t, dtype=float)
    guess = []
    for s in model.states:
        base, order = split_derivative(s)
        lower = sorted((split_derivative(m)[1], m) for m in measured if split_derivative(m)[0] == base
                       and split_derivative(m)[1] < order)
        if s in measured:
            guess.append(float(measured[s][0]))
        elif s in sim.initial_guess:
            guess.append(float(sim.initial_guess[s]))
        elif lower:
            have, name = lower[-1]
            method = "savgol" if data.derivatives == "exact" else data.derivatives
            guess.append(float(estimate(t, measured[name], order - have, method, data.window, name, data.cutoff).values[order - have][0]))
        else:
            guess.append(0.0)
    as_tensor = lambda v: torch.as_tensor(np.asarray(v, dtype=float).copy(), dtype=dtype)
    external = torch.stack([as_tensor(measured[n]) for n in model.external], -1) if model.external \
        else torch.zeros(t.size, 0, dtype=dtype)
    return Record.build(as_tensor(t), external, torch.stack([as_tensor(measured[o]) for o in outputs]),
                        torch.tensor(guess, dtype=dtype), sim.input_hold)


def groups(spec: ModelSpec, coupling: str) -> list[tuple[Equation, ...]]:
    """The equations simulated together: all of them (joint), or one at a time (separate)."""
    return [spec.equations] if coupling == "joint" else [(eq,) for eq in spec.equations]


def build_model(spec: ModelSpec, group: tuple[Equation, ...]) -> SystemModel:
    """The group's states are simulated; inputs and every other state are read from the data."""
    bases = {split_derivative(eq.target)[0] for eq in group}
    external = tuple(spec.inputs) + tuple(s for s in spec.states if split_derivative(s)[0] not in bases)
    return SystemModel.build(spec, group, external)


def output_states(config: Config, spec: ModelSpec, model: SystemModel) -> tuple[str, ...]:
    """The simulated states compared with the data (``simulation.output``, else the measured ones)."""
    sim = config.adaptation.simulation
    for i, name in enumerate(sim.output):
        if name not in spec.states:
            raise ConfigError(f"adaptation.simulation.output[{i}]", f"{name!r} is not a state of the model")
    chosen = tuple(o for o in sim.output if o in model.states)
    if not sim.output:
        chosen = tuple(s for s in model.states if s in config.data.columns)
    if not chosen:
        raise ConfigError("adaptation.simulation.output", f"name the measured states among {list(model.states)} "
                          "that the simulation is compared with")
    return chosen


def state_limits(config: Config, states: tuple[str, ...], dtype=torch.float64, device=None) -> torch.Tensor | None:
    """The range of every simulated state (2, S) from ``simulation.saturation`` (None: unbounded);
    ranges of states another group simulates are ignored."""
    saturation = config.adaptation.simulation.saturation
    if not saturation:
        return None
    for name, (low, high) in saturation.items():
        key = f"adaptation.simulation.saturation.{name}"
        if name not in config.model.states:
            raise ConfigError(key, f"{name!r} is not a state of the model")
        if low is not None and high is not None and not low < high:
            raise ConfigError(key, f"the range [{low}, {high}] is empty: give [low, high] with low < high")
    bound = lambda name, k, default: default if saturation.get(name, (None, None))[k] is None else float(saturation[name][k])
    return torch.tensor([[bound(x, 0, -torch.inf) for x in states], [bound(x, 1, torch.inf) for x in states]],
                        dtype=dtype, device=device)


def function_scale(data: SimulationData, choice, gamma, theta, theta_fixed, initial) -> torch.Tensor:
    """RMS of every adjustment function along a simulation (T, G) (``normalize: rms``)."""
    p = Parameters(gamma, choice, theta, theta_fixed, torch.ones_like(data.scale))
    states = simulate(data.model, data.record, p, initial, data.method, data.substeps, data.limits)  # (T, N, S)
    external = data.record.external.unsqueeze(0).expand(states.shape[:-1] + data.record.external.shape[-1:])
    values = data.model.values(data.record.t.view(1, -1).expand(states.shape[:-1]), states, external)
    f = data.model.functions_at(values, states.shape[:-1])
    return torch.sqrt((f * f).mean(-2)).clamp_min(torch.finfo(f.dtype).tiny)


@dataclass(frozen=True)
class Prepared:
    """A group ready for Algorithm 1: the data (with fitted initial states and function scale) and
    the theta-retuned starting model's theta (T, Qa), (T, P)."""

    data: SimulationData
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    validation: Record | None


def prepare(config: Config, spec: ModelSpec, group: tuple[Equation, ...], parameters: dict | list[dict],
            base_dir: Path, dtype=torch.float64, device=None) -> Prepared:
    """Records, the starting model's fit of theta and initial states, and the function scale;
    a list of parameter sets gives one trial each."""
    model = build_model(spec, group)
    outputs = output_states(config, spec, model)
    train, validation = load_records(config, spec, model, outputs, base_dir, dtype)
    train, validation = train.to(device), None if validation is None else validation.to(device)
    a, sim = config.adaptation, config.adaptation.simulation
    trials = parameters if isinstance(parameters, list) else [parameters]
    thetas = [[spec.theta(eq, values).to(device=device, dtype=dtype) for eq in group] for values in trials]
    theta = torch.stack([torch.stack([th[e][i] for e, i in model.adjustable]) for th in thetas])
    theta_fixed = torch.stack([torch.stack([th[e][i] for e, i in model.fixed]) for th in thetas]) if model.fixed \
        else theta.new_zeros(len(trials), 0)
    t, q, p, s = theta.shape[0], theta.shape[-1], theta_fixed.shape[-1], len(model.states)
    free = torch.tensor([a.theta == "varpro"] * (q + p) + [sim.initial == "estimate"] * s, device=device)
    data = SimulationData(model, train, tuple(model.states.index(o) for o in outputs), train.guess.expand(t, -1),
                          torch.ones(t, len(model.functions), dtype=dtype, device=device), free, sim.method,
                          sim.substeps, sim.relative_step, sim.refit_steps, state_limits(config, model.states, dtype, device))
    unadjusted = torch.full((t, 1, q), model.unadjusted, dtype=torch.long, device=device)
    gamma = theta.new_zeros(t, 1, q)
    z = torch.cat([theta, theta_fixed, data.initial], -1).unsqueeze(1)
    z, _ = fit_parameters(data, unadjusted, gamma, z, free, sim.prefit_steps)
    theta, theta_fixed, initial = (v[:, 0] for v in _unpacked(z, q, p))
    data = replace(data, initial=initial)
    if a.normalize == "rms":
        data = replace(data, scale=function_scale(data, unadjusted[:, 0], gamma[:, 0], theta, theta_fixed, initial))
    return Prepared(data, theta, theta_fixed, validation)


def free_run(data: SimulationData, record: Record, choice, gamma, theta, theta_fixed, steps: int = 6,
             estimate_initial: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """Simulate a model (T rows of choice, gamma, theta) on ``record``; only its initial states are
    fitted (by least squares on the record's outputs). Returns outputs (T, O, N) and initial states."""
    on_record = replace(data, record=record, initial=record.guess.expand(theta.shape[0], -1))
    q, p, s = theta.shape[-1], theta_fixed.shape[-1], record.guess.shape[-1]
    free = torch.tensor([False] * (q + p) + [estimate_initial] * s, device=theta.device)
    z = torch.cat([theta, theta_fixed, on_record.initial], -1).unsqueeze(1)
    z, out = fit_parameters(replace(on_record, free=free), choice.unsqueeze(1), gamma.unsqueeze(1), z, free, steps)
    return out[:, 0].unflatten(-1, (record.outputs.shape[0], -1)), z[:, 0, q + p:]


def rmse(record: Record, simulated: torch.Tensor) -> list[float]:
    """Root-mean-square error of each output (O,) for one simulated row (O, N)."""
    return torch.sqrt(((record.outputs - simulated) ** 2).mean(-1)).tolist()


def adapt_simulation(config: Config, spec: ModelSpec, parameters: dict, base_dir: Path, on_trainer=None):
    """Algorithm 1 with simulation-based evaluation on every group of equations -> RunResult.

    ``RunResult.data['simulation']`` holds, per group: the outputs, the fitted initial states and
    the free-run RMSE of the theta-retuned starting model and of the adapted model on the training
    and (if configured) validation records (initial states fitted on each record).
    """
    from .api import step_options
    from .result import RunResult
    from .trainer import Trainer

    a = config.adaptation
    dtype, device = getattr(torch, a.dtype), torch.device(a.device)
    results, reports = [], []
    for group in groups(spec, a.simulation.coupling):
        prepared = prepare(config, spec, group, parameters, base_dir, dtype, device)
        data, model = prepared.data, prepared.data.model
        trainer = Trainer(step_options(config), a.round_robin_steps, a.refinement_steps, a.chunk_size,
                          evaluator=SimulationEvaluator)
        if on_trainer is not None:
            on_trainer(trainer, label_equation(model))
        start = torch.tensor([group[e].components[i].start for e, i in model.adjustable], dtype=dtype, device=device)
        fit = trainer.fit(data, prepared.theta, prepared.theta_fixed, start, choices=model.choices(device))
        results.extend(equation_results(model, fit, prepared))
        reports.append(report(prepared, fit))
    return RunResult(results, config.model_dump(mode="json"),
                     {"source": config.data.file or f"system:{config.data.system}", "evaluation": "simulation",
                      "nominal_parameters": parameters, "simulation": reports})


def label_equation(model: SystemModel) -> Equation:
    """A stand-in equation naming the group for callbacks: its adjustments are the group's
    functions, so ``candidate_label`` reads joint candidates."""
    return Equation(",".join(eq.target for eq in model.equations), (), model.functions)


def report(prepared: Prepared, fit) -> dict:
    """Fitted initial states, the theta-retuned starting model's theta per equation (data units) and
    free-run RMSE (retuned start vs adapted) on training and validation."""
    data, model = prepared.data, prepared.data.model
    unadjusted = torch.full_like(fit.choices[:1].expand(fit.gamma.shape[0], -1), model.unadjusted)
    chosen = fit.choices[fit.winner]
    rows = {"start": (unadjusted, torch.zeros_like(fit.gamma), prepared.theta, prepared.theta_fixed),
            "adapted": (chosen, fit.gamma, fit.theta, fit.theta_fixed)}
    retuned = {eq.target: [0.0] * len(eq.components) for eq in model.equations}
    for slots, values in ((model.adjustable, prepared.theta), (model.fixed, prepared.theta_fixed)):
        for k, (e, i) in enumerate(slots):
            retuned[model.equations[e].target][i] = float(values[0, k])
    out = {"outputs": [model.states[i] for i in data.outputs],
           "initial": dict(zip(model.states, (fit.initial if fit.initial is not None else data.initial)[0].tolist())),
           "retuned_theta": retuned, "free_run_rmse": {}}
    both = [torch.cat([r[k] for r in rows.values()]) for k in range(4)]  # start and adapted as two rows
    scale = data.scale.expand(len(rows), -1)
    for name, record in (("train", data.record), ("validation", prepared.validation)):
        if record is not None:
            simulated, _ = free_run(replace(data, scale=scale), record, *both, steps=3)
            out["free_run_rmse"][name] = {label: rmse(record, simulated[k]) for k, label in enumerate(rows)}
    return out


def equation_results(model: SystemModel, fit, prepared: Prepared, trial: int = 0) -> list:
    """One :class:`EquationResult` per equation of the group (measures and ranking are the group's)."""
    from .result import EquationResult, format_component, format_equation

    winner = int(fit.winner[trial])
    choice = fit.choices[winner]
    scale = prepared.data.scale[trial]
    gamma = fit.gamma[trial]
    theta = fit.theta[trial] * scale[choice] ** (-gamma)
    labels = lambda c: [model.functions[int(f)].text for f in c]
    order = torch.argsort(fit.ranking_fitness[trial], descending=True).tolist()
    ranking = [{"candidate": c, "adjustments": labels(fit.choices[c]), "fitness": float(fit.ranking_fitness[trial, c]),
                "exponents": fit.ranking_gamma[trial, c].tolist(), "diverged": bool(fit.diverged[trial, c])}
               for c in order]
    pick = lambda d: {k: float(v[trial]) for k, v in d.items()}
    results = []
    for e, eq in enumerate(model.equations):
        thetas, terms, adjustments, exponents, start_thetas = [], [], [], [], []
        for i, component in enumerate(eq.components):
            if (e, i) in model.adjustable:
                k = model.adjustable.index((e, i))
                function = int(choice[k])
                local = [f.text for f in eq.adjustments].index(model.functions[function].text)
                thetas.append(float(theta[k]))
                start_thetas.append(float(prepared.theta[trial, k]))
                terms.append(format_component(eq, i, local, float(gamma[k])))
                adjustments.append(model.functions[function].text)
                exponents.append(float(gamma[k]))
            else:
                k = model.fixed.index((e, i))
                thetas.append(float(fit.theta_fixed[trial, k]))
                start_thetas.append(float(prepared.theta_fixed[trial, k]))
                terms.append(format_component(eq, i, None, None))
                adjustments.append(None)
                exponents.append(None)
        results.append(EquationResult(
            target=eq.target, equation=format_equation(eq.target, thetas, terms),
            start_equation=format_equation(eq.target, start_thetas, [c.term.text for c in eq.components]),
            adjustments=adjustments, exponents=exponents, theta=thetas, start=pick(fit.start), final=pick(fit.final),
            ranking=ranking, diverged=int(fit.diverged[trial].sum())))
    return results


@dataclass(frozen=True)
class FreeRun:
    """Free runs of B models on one record: the record, the output names and the simulated states
    (B, N, S) of ``model`` (initial states fitted on the record's outputs)."""

    record: Record
    model: SystemModel
    outputs: tuple[str, ...]
    states: torch.Tensor

    @property
    def simulated(self) -> torch.Tensor:
        """Simulated outputs (B, O, N)."""
        return self.states[..., [self.model.states.index(o) for o in self.outputs]].movedim(-1, -2)


def free_runs(config: Config, spec: ModelSpec, models: dict[str, list], base_dir: Path | str,
              records: tuple[str, ...] = ("train", "validation"), steps: int = 6,
              dtype=torch.float64) -> dict[str, FreeRun]:
    """Every model of ``spec`` run jointly (all equations) under the measured inputs of each of
    ``records`` (those configured), with only its initial states fitted (``steps``
    Levenberg-Marquardt steps). ``models`` maps a label to one entry per equation with
    ``adjustments`` (per component: the adjustment text, or None for an unadjusted or fixed
    component), ``exponents`` and ``theta`` in the data's units, e.g.
    :class:`~msam_torch.result.EquationResult`."""
    model = build_model(spec, spec.equations)
    outputs = output_states(config, spec, model)
    train, validation = load_records(config, spec, model, outputs, Path(base_dir), dtype)
    texts = [f.text for f in model.functions]
    rows = []
    for entries in models.values():
        choice, gamma, theta, theta_fixed = [], [], [], []
        for e, i in model.adjustable:
            entry = entries[e]
            text = entry.adjustments[i]
            choice.append(model.unadjusted if text is None else texts.index(text))
            gamma.append(0.0 if entry.exponents[i] is None else float(entry.exponents[i]))
            theta.append(float(entry.theta[i]))
        theta_fixed = [float(entries[e].theta[i]) for e, i in model.fixed]
        rows.append((choice, gamma, theta, theta_fixed))
    as_tensor = lambda k, kind=dtype: torch.tensor([r[k] for r in rows], dtype=kind).reshape(len(rows), -1)
    choice, gamma, theta, theta_fixed = as_tensor(0, torch.long), as_tensor(1), as_tensor(2), as_tensor(3)
    sim = config.adaptation.simulation
    scale = torch.ones(len(rows), len(model.functions), dtype=dtype)
    data = SimulationData(model, train, tuple(model.states.index(o) for o in outputs), train.guess.unsqueeze(0), scale,
                          torch.zeros(theta.shape[-1] + theta_fixed.shape[-1] + len(model.states), dtype=torch.bool),
                          sim.method, sim.substeps, sim.relative_step, limits=state_limits(config, model.states, dtype))
    out = {}
    for name, record in (("train", train), ("validation", validation)):
        if record is not None and name in records:
            _, initial = free_run(data, record, choice, gamma, theta, theta_fixed, steps,
                                  estimate_initial=sim.initial == "estimate")
            states = simulate(model, record, Parameters(gamma, choice, theta, theta_fixed, scale), initial,
                              sim.method, sim.substeps, data.limits)
            if data.limits is not None:
                states = torch.clamp(states, data.limits[0], data.limits[1])
            out[name] = FreeRun(record, model, outputs, states)
    return out


def free_run_models(config: Config, spec: ModelSpec, models: dict[str, list], base_dir: Path | str,
                    records: tuple[str, ...] = ("train", "validation"), steps: int = 6, dtype=torch.float64) -> dict:
    """Free-run RMSE of several models (see :func:`free_runs`) on the training and validation
    records: ``{"outputs": [...], "free_run_rmse": {record: {label: [rmse per output]}},
    "simulated": {record: {label: (O, N) list}}}``."""
    runs = free_runs(config, spec, models, base_dir, records, steps, dtype)
    out = {"outputs": list(output_states(config, spec, build_model(spec, spec.equations))), "free_run_rmse": {},
           "simulated": {}}
    for name, run in runs.items():
        simulated = run.simulated
        out["free_run_rmse"][name] = {label: rmse(run.record, simulated[k]) for k, label in enumerate(models)}
        out["simulated"][name] = {label: simulated[k].tolist() for k, label in enumerate(models)}
    return out
