"""Systems with known answers, simulated with torchdiffeq: the controlled cases of Table 1.

Shared by the tests, the experiments and the docs. :func:`measure` returns every signal the
model specs may read: each state, its exact time derivative (from the true right-hand side), the
inputs and the time ``t``. :func:`perturb_parameters` draws the parametric error of docs/design.md 2.8.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import torch

from msam_torch.data.cache import cached
from msam_torch.errors import ConfigError
from msam_torch.model.spec import derivative_name, split_derivative

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
    # Table 1 and docs/design.md 2.9: step u = 1000 N from rest, t in [0, 3] s, N = 1000.
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


def measure(system: System, parameters: Mapping[str, float] | None = None, dtype=torch.float64,
             rtol: float = 1e-10, atol: float = 1e-10) -> dict[str, torch.Tensor]:
    """Simulate ``system`` on its grid; return ``t``, states, exact derivatives and inputs (N,).

    The trajectory is kept in :func:`~msam_torch.data.cache.cached` under a fingerprint of the
    system's code and values, so a system is integrated once per machine."""
    p = dict(system.parameters if parameters is None else parameters)
    t = torch.linspace(0.0, system.t_end, system.samples, dtype=dtype)
    func = lambda tt, s: system.rhs(tt, s, p, {k: u(tt) for k, u in system.inputs.items()})

    def integrate():
        from torchdiffeq import odeint  # only on a cache miss: torchdiffeq imports scipy.integrate

        return odeint(func, torch.tensor(system.initial, dtype=dtype), t, rtol=rtol, atol=atol, method="dopri5")

    trajectory = cached(integrate, "system", system, p, dtype, rtol, atol)
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
    upwards instead (docs/design.md 2.8).
    """
    names = list(parameters)
    if level == 0 or not names:
        return dict(parameters)
    shares = -torch.log(torch.rand(len(names), generator=generator, dtype=torch.float64))
    shares = level * shares / shares.sum()
    signs = torch.where(torch.rand(len(names), generator=generator, dtype=torch.float64) < 0.5, -1.0, 1.0)
    signs = torch.where(1.0 - shares < floor, torch.ones_like(signs), signs)
    return {n: float(parameters[n]) * (1.0 + float(s * r)) for n, s, r in zip(names, signs, shares)}


# ---------------------------------------------------------------------------------------------
# Withheld-effect systems (sim-to-real gap diagnosis): a true system with a known effect, the
# starting model without it, and a second excitation for held-out data.


def multisine(frequencies: tuple[float, ...], amplitude: float, offset: float = 0.0) -> Callable[[torch.Tensor], torch.Tensor]:
    """``offset + amplitude * sum_k sin(w_k t + phi_k) / sqrt(K/2)`` with Schroeder phases
    ``phi_k = -pi k (k - 1) / K`` (deterministic, low crest factor); RMS about ``amplitude``."""
    k = len(frequencies)
    phases = [-math.pi * i * (i - 1) / k for i in range(1, k + 1)]
    norm = math.sqrt(k / 2)

    def u(t):
        w, phi = (torch.tensor(v, dtype=t.dtype, device=t.device) for v in (frequencies, phases))
        return offset + amplitude * torch.sin(t.unsqueeze(-1) * w + phi).sum(-1) / norm

    return u


def _smooth_sign(v, width):
    return torch.tanh(v / width)


def _msd(effect: Callable) -> Rhs:
    """``m x'' = -c x' - k x - effect(x, x', p, u) + u``."""
    def rhs(t, s, p, u):
        x, v = s[..., 0], s[..., 1]
        force = -p["c"] * v - p["k"] * x - effect(x, v, p, u) + u["u"]
        return torch.stack([v, force / p["m"]], -1)
    return rhs


def _msd_input_dead_zone(t, s, p, u):
    x, v = s[..., 0], s[..., 1]
    w = u["u"]
    force = -p["c"] * v - p["k"] * x + torch.sign(w) * torch.relu(w.abs() - p["d"])
    return torch.stack([v, force / p["m"]], -1)


def _msd_backlash(t, s, p, u):
    """The spring acts through a play (backlash) of half-width b: z follows x once the play is taken
    up (smoothed over ``width``); force -k z."""
    x, v, z = s[..., 0], s[..., 1], s[..., 2]
    w = x - z
    z_dot = (torch.relu(v) * torch.sigmoid((w - p["b"]) / p["width"])
             - torch.relu(-v) * torch.sigmoid((-w - p["b"]) / p["width"]))
    force = -p["c"] * v - p["k"] * z + u["u"]
    return torch.stack([v, force / p["m"], z_dot], -1)


def _vdp_forced(t, s, p, u):
    x, v = s[..., 0], s[..., 1]
    return torch.stack([v, p["mu"] * (1 - x**2) * v - p["w2"] * x], -1)


def _tank(t, s, p, u):
    h = s[..., 0]
    return (u["u"] - p["a"] * torch.sqrt(h.clamp_min(0.0))).unsqueeze(-1) / p["A"]


_MSD = {"m": 1.0, "c": 0.5, "k": 4.0}
_TRAIN_U = multisine((0.4, 0.7, 1.1, 1.5, 1.9, 2.4, 3.0, 3.7), 2.5)
_HELD_U = multisine((0.5, 0.9, 1.3, 1.7, 2.2, 2.8), 2.2)
_N, _T_END = 2000, 40.0


def _pair(name: str, rhs: Rhs, parameters: dict, states=("x", "x_dot"), initial=(0.0, 0.0),
          held_initial=None, train_u=_TRAIN_U, held_u=_HELD_U, measured=("x", "u")) -> dict[str, System]:
    inputs = lambda u: {"u": u} if u is not None else {}
    return {
        name: System(states, parameters, rhs, initial, _T_END, _N, inputs(train_u), measured),
        f"{name}_heldout": System(states, parameters, rhs, held_initial or initial, _T_END, _N, inputs(held_u), measured),
    }


_MSD_MODEL = {
    "states": ["x", "x_dot"], "inputs": ["u"], "parameters": {"m": 1.0, "c": 0.5, "k": 4.0},
    "quantities": {"x": "position", "x_dot": "velocity", "u": "force"},
    "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-c/m"}, {"term": "x", "theta": "-k/m"},
                                                      {"term": "u", "theta": "1/m", "adjustable": False}],
                   "adjustments": ["abs(x_dot)", "abs(x)"]}],
}


@dataclass(frozen=True)
class WithheldEffect:
    """A diagnosis case: the true ``system`` (training excitation) and ``held_out`` (another
    excitation) in :data:`SYSTEMS`, the starting ``model`` (a config ``model`` section) without the
    effect, the expected answer, and where the effect acts (``active``: signals -> bool mask)."""

    system: str
    held_out: str
    model: dict
    expected: str  # catalogue name, 'no significant gap' or 'gap not explained by a catalogued effect'
    kind: str  # 'in_catalogue', 'null' or 'out_of_catalogue'
    active: Callable[[Mapping[str, torch.Tensor]], torch.Tensor] | None = None


WITHHELD_SYSTEMS: dict[str, System] = {
    **_pair("msd_linear", _msd(lambda x, v, p, u: 0.0 * x), dict(_MSD)),
    **_pair("msd_coulomb", _msd(lambda x, v, p, u: p["fc"] * _smooth_sign(v, 0.01)), {**_MSD, "fc": 0.6}),
    **_pair("msd_quadratic_drag", _msd(lambda x, v, p, u: p["cq"] * v * v.abs()), {**_MSD, "cq": 0.4}),
    **_pair("msd_hardening", _msd(lambda x, v, p, u: p["k3"] * x**3), {**_MSD, "k3": 2.0}),
    **_pair("msd_softening", _msd(lambda x, v, p, u: -p["k3"] * x**3), {**_MSD, "k3": 0.2}),
    **_pair("msd_power_damping", _msd(lambda x, v, p, u: p["cp"] * v * v.abs().clamp_min(1e-12) ** 0.5),
            {**_MSD, "cp": 0.8}),
    **_pair("msd_clearance", _msd(lambda x, v, p, u: p["k2"] * torch.sign(x) * torch.relu(x.abs() - p["d"])),
            {**_MSD, "k2": 6.0, "d": 0.6}),
    **_pair("msd_input_dead_zone", _msd_input_dead_zone, {**_MSD, "d": 1.5}),
    **_pair("msd_backlash", _msd_backlash, {**_MSD, "b": 0.25, "width": 0.01}, states=("x", "x_dot", "z"),
            initial=(0.0, 0.0, 0.0)),
    **_pair("vdp_from_linear", _vdp_forced, {"mu": 1.0, "w2": 1.0}, initial=(0.5, 0.0), held_initial=(2.5, -1.0),
            train_u=None, held_u=None, measured=("x",)),
    **_pair("tank_torricelli", _tank, {"A": 1.0, "a": 0.5}, states=("h",), initial=(1.0,),
            train_u=multisine((0.15, 0.3, 0.5, 0.8, 1.2), 0.15, 0.5),
            held_u=multisine((0.2, 0.4, 0.65, 1.0), 0.13, 0.45), measured=("h", "u")),
}
SYSTEMS.update(WITHHELD_SYSTEMS)

WITHHELD: dict[str, WithheldEffect] = {
    "msd_coulomb": WithheldEffect("msd_coulomb", "msd_coulomb_heldout", _MSD_MODEL, "Coulomb friction", "in_catalogue"),
    "msd_quadratic_drag": WithheldEffect("msd_quadratic_drag", "msd_quadratic_drag_heldout", _MSD_MODEL,
                                         "quadratic drag", "in_catalogue"),
    "msd_hardening": WithheldEffect("msd_hardening", "msd_hardening_heldout", _MSD_MODEL,
                                    "hardening cubic stiffness", "in_catalogue"),
    "msd_softening": WithheldEffect("msd_softening", "msd_softening_heldout", _MSD_MODEL,
                                    "softening cubic stiffness", "in_catalogue"),
    "msd_power_damping": WithheldEffect("msd_power_damping", "msd_power_damping_heldout", _MSD_MODEL,
                                        "power-law damping", "in_catalogue"),
    "vdp_from_linear": WithheldEffect(
        "vdp_from_linear", "vdp_from_linear_heldout",
        {"states": ["x", "x_dot"], "parameters": {"mu": 1.0, "w2": 1.0}, "quantities": {"x": "position"},
         "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "mu"}, {"term": "x", "theta": "-w2"}],
                        "adjustments": ["abs(x_dot)", "abs(x)"]}]},
        "van der Pol-type damping", "in_catalogue"),
    "tank_torricelli": WithheldEffect(
        "tank_torricelli", "tank_torricelli_heldout",
        {"states": ["h"], "inputs": ["u"], "parameters": {"A": 1.0, "a": 0.25}, "quantities": {"h": "level", "u": "flow"},
         "equations": [{"target": "h_dot", "components": [{"term": "h", "theta": "-a/A"},
                                                          {"term": "u", "theta": "1/A", "adjustable": False}],
                        "adjustments": ["abs(h)"]}]},
        "Torricelli outflow", "in_catalogue"),
    "msd_linear": WithheldEffect("msd_linear", "msd_linear_heldout", _MSD_MODEL, "no significant gap", "null"),
    "msd_clearance": WithheldEffect("msd_clearance", "msd_clearance_heldout", _MSD_MODEL,
                                    "gap not explained by a catalogued effect", "out_of_catalogue",
                                    active=lambda s: s["x"].abs() > 0.6),
    "msd_input_dead_zone": WithheldEffect("msd_input_dead_zone", "msd_input_dead_zone_heldout", _MSD_MODEL,
                                          "gap not explained by a catalogued effect", "out_of_catalogue"),
    "msd_backlash": WithheldEffect("msd_backlash", "msd_backlash_heldout", _MSD_MODEL,
                                   "gap not explained by a catalogued effect", "out_of_catalogue"),
}
