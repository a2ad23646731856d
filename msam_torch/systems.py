"""Systems with known answers, simulated with torchdiffeq: the controlled cases of Table 1.

Shared by the tests, the experiments and the docs. :func:`simulate` returns every signal the
model specs may read: each state, its exact time derivative (from the true right-hand side), the
inputs and the time ``t``. :func:`perturb_parameters` draws the parametric error of design.md 2.8.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import torch
from torchdiffeq import odeint

from .errors import ConfigError
from .spec import derivative_name, split_derivative

Rhs = Callable[[torch.Tensor, torch.Tensor, Mapping[str, float], Mapping[str, torch.Tensor]], torch.Tensor]


@dataclass(frozen=True)
class System:
    """A true system: ``d state/dt = rhs(t, state, parameters, inputs)``, its excitation and grid."""

    states: tuple[str, ...]
    parameters: Mapping[str, float]
    rhs: Rhs
    initial: tuple[float, ...]
    t_end: float
    samples: int = 1000
    inputs: Mapping[str, Callable[[torch.Tensor], torch.Tensor]] = field(default_factory=dict)
    measured: tuple[str, ...] = ()  # signals a sensor would record (the rest are estimated)


def _harmonic(t, s, p, u):
    x, v = s[..., 0], s[..., 1]
    return torch.stack([v, (-p["c"] * v * v.abs() - p["k"] * x**3 + u["u"]) / p["m"]], -1)


def _vanderpol(t, s, p, u):
    x, v = s[..., 0], s[..., 1]
    return torch.stack([v, -p["eta1"] * x**2 * v + p["eta2"] * v - p["eta3"] * x], -1)


def _sode3(t, s, p, u):
    x1, x2, x3 = s[..., 0], s[..., 1], s[..., 2]
    return torch.stack(
        [
            p["th1"] * x1 * x3 + p["th2"] * x2 * x3 + p["th3"] * x3 * x3,
            p["th4"] * x1 * x2 + p["th5"] * x1 * x3 + p["th6"] * x2 * x3,
            p["th7"] * x1 * x2 + p["th8"] * x1 * x3 + p["th9"] * x2 * x3,
        ],
        -1,
    )


def step_input(level: float) -> Callable[[torch.Tensor], torch.Tensor]:
    return lambda t: torch.full_like(t, level)


SYSTEMS: dict[str, System] = {
    # Table 1 and design.md 2.9: step u = 1000 N from rest, t in [0, 3] s, N = 1000.
    "harmonic": System(("x", "x_dot"), {"m": 375.0, "c": 9800.0, "k": 130000.0}, _harmonic, (0.0, 0.0), 3.0,
                       inputs={"u": step_input(1000.0)}, measured=("x", "u")),
    # x(0) = 0, x_dot(0) = -1, t in [0, 20].
    "vanderpol": System(("x", "x_dot"), {"eta1": 1.5, "eta2": 1.5, "eta3": 1.0}, _vanderpol, (0.0, -1.0), 20.0,
                        measured=("x",)),
    # x(0) = [5, 0, 1], t in [0, 2], N = 1000.
    "sode3": System(("x1", "x2", "x3"),
                    {"th1": -3.0, "th2": -2.0, "th3": -3.0, "th4": -3.0, "th5": 1.0, "th6": -3.0,
                     "th7": 3.0, "th8": 3.0, "th9": -1.0},
                    _sode3, (5.0, 0.0, 1.0), 2.0, measured=("x1", "x2", "x3")),
}


def get_system(name: str, key: str = "data.system") -> System:
    try:
        return SYSTEMS[name]
    except KeyError:
        raise ConfigError(key, f"unknown system {name!r} (known: {', '.join(SYSTEMS)})") from None


def simulate(system: System, parameters: Mapping[str, float] | None = None, dtype=torch.float64,
             rtol: float = 1e-10, atol: float = 1e-10) -> dict[str, torch.Tensor]:
    """Simulate ``system`` on its grid; return ``t``, states, exact derivatives and inputs (N,)."""
    p = dict(system.parameters if parameters is None else parameters)
    t = torch.linspace(0.0, system.t_end, system.samples, dtype=dtype)
    func = lambda tt, s: system.rhs(tt, s, p, {k: u(tt) for k, u in system.inputs.items()})
    trajectory = odeint(func, torch.tensor(system.initial, dtype=dtype), t, rtol=rtol, atol=atol, method="dopri5")
    inputs = {k: u(t) for k, u in system.inputs.items()}
    rates = system.rhs(t, trajectory, p, inputs)
    signals = {"t": t, **inputs}
    for i, name in enumerate(system.states):
        base, order = split_derivative(name)
        signals[name] = trajectory[:, i]
        signals[derivative_name(base, order + 1)] = rates[:, i]
    return signals


def perturb_parameters(parameters: Mapping[str, float], level: float, generator: torch.Generator,
                       floor: float = 0.05) -> dict[str, float]:
    """Nominal parameters with total relative error ``sum |p* - p~| / |p*| = level``.

    The error is split at random (flat Dirichlet), each share gets a random sign, and a share that
    would push a parameter below ``floor`` of its true magnitude (or through zero) is applied
    upwards instead (design.md 2.8).
    """
    names = list(parameters)
    if level == 0 or not names:
        return dict(parameters)
    shares = -torch.log(torch.rand(len(names), generator=generator, dtype=torch.float64))
    shares = level * shares / shares.sum()
    signs = torch.where(torch.rand(len(names), generator=generator, dtype=torch.float64) < 0.5, -1.0, 1.0)
    signs = torch.where(1.0 - shares < floor, torch.ones_like(signs), signs)
    return {n: float(parameters[n]) * (1.0 + float(s * r)) for n, s, r in zip(names, signs, shares)}
