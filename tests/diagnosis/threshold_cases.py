"""Generated records of threshold effects and of power laws (solve_ivp, seeded), shared by
tests/diagnosis/test_thresholds.py and experiments/thresholds.py: a mass-spring-damper whose
actuator saturates or has a dead zone (the force's component fixed), whose spring force saturates,
or with a power-law friction or stiffness; a tank that overflows above a level. Each returns the
config, a training and a held-out record, the effect's name and the threshold (None for a power law)."""
from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from msam_torch.data.systems import WITHHELD

SAMPLES = 3000
OSCILLATOR = WITHHELD["msd_linear"].model  # m x_ddot = -c x_dot - k x + u, the force's component fixed


def clip(s, c):
    return np.clip(s, -c, c)


def dead_zone(s, c):
    return np.sign(s) * np.maximum(np.abs(s) - c, 0.0)


def _multisine(rng, t, amplitude):
    freqs = np.array([0.15, 0.3, 0.5, 0.7, 0.95, 1.2]) * (1 + 0.1 * rng.standard_normal(6))
    phases = rng.uniform(0, 2 * np.pi, 6)
    return lambda tt: amplitude * np.sin(np.multiply.outer(tt, 2 * np.pi * freqs) + phases).sum(-1) / np.sqrt(3)


def _oscillator_record(rng, u, rhs, noise):
    t = np.linspace(0.0, 40.0, SAMPLES)
    x = solve_ivp(lambda tt, s: rhs(s[0], s[1], float(u(tt))), (0.0, 40.0), [0.0, 0.0], t_eval=t,
                  rtol=1e-9, atol=1e-9, max_step=0.05).y[0]
    return pd.DataFrame({"t": t, "x": x + noise * x.std() * rng.standard_normal(SAMPLES), "u": u(t)})


def oscillator(seed: int, effect: str, noise: float = 0.01):
    """The oscillator ``x'' = -0.5 x' - 4 x + u`` with ``effect``: 'saturation' (u clipped where
    10-30 % of the training record's samples lie beyond), 'dead zone' (u's dead band holding 10-30 %
    of them), 'spring saturation' (the spring's x clipped where 10-30 % of the linear response's
    samples lie beyond), or a power law: 'Coulomb friction', 'quadratic drag', 'hardening cubic
    stiffness'."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 40.0, SAMPLES)
    inputs = [_multisine(rng, t, 7.0) for _ in range(2)]
    share = rng.uniform(0.1, 0.3)
    linear = lambda x, v, u: -0.5 * v - 4.0 * x + u
    beyond = lambda values: float(np.quantile(np.abs(values), 1 - share))
    threshold = {"saturation": beyond(inputs[0](t)), "dead zone": float(np.quantile(np.abs(inputs[0](t)), share)),
                 "spring saturation": beyond(_oscillator_record(rng, inputs[0], lambda x, v, u: [v, linear(x, v, u)],
                                                                0.0).x)}.get(effect)
    law = {"saturation": lambda x, v, u: -0.5 * v - 4.0 * x + clip(u, threshold),
           "dead zone": lambda x, v, u: -0.5 * v - 4.0 * x + dead_zone(u, threshold),
           "spring saturation": lambda x, v, u: -0.5 * v - 4.0 * clip(x, threshold) + u,
           "Coulomb friction": lambda x, v, u: linear(x, v, u) - 1.5 * np.tanh(v / 1e-3),  # sign(v), smoothed
           "quadratic drag": lambda x, v, u: linear(x, v, u) - 0.4 * v * abs(v),
           "hardening cubic stiffness": lambda x, v, u: linear(x, v, u) - 1.0 * x**3}[effect]
    rhs = lambda x, v, u: [v, law(x, v, u)]
    config = {"model": OSCILLATOR, "data": {"time": "t", "columns": {"x": "x", "u": "u"}}}
    name = "saturation" if effect == "spring saturation" else effect
    records = [_oscillator_record(rng, u, rhs, noise) for u in inputs]
    return config, records[0], records[1], name, threshold


def tank(seed: int, noise: float = 0.01):
    """A tank ``h' = q / A - k sqrt(h)`` that overflows above a level ``c`` (a weir,
    ``- b max(0, h - c)^1.5``), ``c`` where 10-30 % of the level's samples lie above it without it."""
    rng = np.random.default_rng(seed)
    area, k, b = 1.0, 0.2, 2.0
    t = np.linspace(0.0, 600.0, 3000)
    inflows = [_multisine(rng, t / 15.0, 0.035) for _ in range(2)]

    def level(q, c, b):
        rhs = lambda tt, h: [(0.16 + float(q(tt / 15.0))) / area - k * np.sqrt(max(h[0], 0.0))
                             - b * max(h[0] - c, 0.0) ** 1.5]
        return solve_ivp(rhs, (0.0, 600.0), [0.64], t_eval=t, rtol=1e-9, atol=1e-9, max_step=1.0).y[0]

    free = level(inflows[0], np.inf, 0.0)
    c = float(np.quantile(free, 1 - rng.uniform(0.1, 0.3)))

    def record(q):
        h = level(q, c, b)
        return pd.DataFrame({"t": t, "h": h + noise * h.std() * rng.standard_normal(t.size), "q": 0.16 + q(t / 15.0)})

    model = {"states": ["h"], "inputs": ["q"], "parameters": {"A": area, "k": k},
             "quantities": {"h": "level", "q": "flow"},
             "equations": [{"target": "h_dot", "components": [
                 {"term": "q", "theta": "1/A", "adjustable": False}, {"term": "sqrt(h)", "theta": "-k"}],
                 "adjustments": ["abs(h)"]}]}
    config = {"model": model, "data": {"time": "t", "columns": {"h": "h", "q": "q"}}}
    return config, record(inflows[0]), record(inflows[1]), "overflow", c
