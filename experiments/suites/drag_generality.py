"""Issue 17, acceptance 2 beyond the one oscillator: ``adapt`` and ``diagnose`` with defaults on a
DataFrame of a drawn oscillator whose damping is ``c x_dot |x_dot|^g`` (the starting model's is
linear), position and force measured with 0.5 % noise (``--noise``).

Each seed draws the natural frequency (10^-1.5 .. 10^2.5 rad per time unit), the mass and the
displacement's unit (10^-3 .. 10^3), the equivalent damping ratio (0.05 .. 0.5), the sampling
(15 .. 80 samples per natural period, 2,000 .. 4,000 samples) and the training and held-out
excitations (``msam_torch.zoo.excitation``: multisine, steps or PRBS, band 0.3 .. 3 times the
natural frequency). ``--family drag`` keeps g = 1 (quadratic drag, the issue's case);
``--family power`` draws g in 0.3 .. 1.5. Printed per case: the adapted adjustment and exponent,
the diagnosis's, and whether each is within ``--tolerance`` of g; then the shares.

    python -m experiments.suites.drag_generality --seeds 1000 1100 [--family drag] [--no-diagnose] [--form strong]

Seeds 0-19 were used while developing the weak form of ``adapt``; figures are reported on others.
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from msam_torch import MSAMError, adapt
from msam_torch.diagnosis import DiagnoseOptions, diagnose
from msam_torch.zoo.excitation import draw as draw_excitation

NOISE = 0.005


def draw(seed: int, family: str, noise: float = NOISE) -> dict:
    """A drawn oscillator ``m x'' = -c x'|x'|^g - k x + u``: its true exponent, the starting-model
    config (linear damping at the equivalent ratio) and training and held-out frames."""
    rng = np.random.default_rng(seed)
    wn = 10 ** rng.uniform(-1.5, 2.5)
    m, unit = 10 ** rng.uniform(-3, 3), 10 ** rng.uniform(-3, 3)
    zeta = rng.uniform(0.05, 0.5)
    g = 1.0 if family == "drag" else rng.uniform(0.3, 1.5)
    k = m * wn**2
    v_ref = wn * unit
    c_linear = 2 * zeta * m * wn
    c = c_linear / v_ref**g  # c v|v|^g = c_linear v at |v| = v_ref
    per_period = rng.uniform(15, 80)
    dt = 2 * math.pi / wn / per_period
    samples = int(rng.integers(2000, 4001))
    t = np.arange(samples) * dt
    frames, kinds = [], []
    for part in ("train", "held_out"):
        band = rng.uniform(0.3, 3.0) * wn / (2 * math.pi)  # cycles per time unit
        u, info = draw_excitation(rng, t, 1 / dt, fraction=band * dt)
        force = k * unit * u
        rhs = lambda time, s: [s[1], (-c * s[1] * abs(s[1]) ** g - k * s[0] + np.interp(time, t, force)) / m]
        sol = solve_ivp(rhs, (t[0], t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-9, atol=1e-12 * unit, max_step=dt)
        x = sol.y[0] + noise * sol.y[0].std() * rng.standard_normal(samples)
        frames.append(pd.DataFrame({"time": t, "x": x, "u": force}))
        kinds.append(info["kind"])
    model = {"states": ["x", "x_dot"], "inputs": ["u"], "parameters": {"m": m, "c": c_linear, "k": k},
             "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-c/m"},
                                                              {"term": "x", "theta": "-k/m"},
                                                              {"term": "u", "theta": "1/m", "adjustable": False}],
                            "adjustments": ["abs(x_dot)", "abs(x)"]}]}
    return {"g": g, "config": {"model": model, "data": {"time": "time", "columns": {"x": "x", "u": "u"}}},
            "train": frames[0], "held_out": frames[1], "wn": wn, "per_period": per_period, "samples": samples,
            "excitation": "/".join(kinds)}


def judged(config, train, held_out, run_diagnosis: bool):
    """(adjustment, exponent) found by ``adapt`` and by ``diagnose`` (None when not run or failed)."""
    try:
        (equation,) = adapt(config, data=train).equations
        adapted = (equation.adjustments[0], equation.exponents[0])
    except MSAMError as error:
        adapted = (f"error: {error}", math.nan)
    diagnosed = None
    if run_diagnosis:
        try:
            (gap,) = diagnose(config, data=train, validation=held_out,
                              options=DiagnoseOptions(bootstrap=8, free_run=False)).equations
            diagnosed = (gap.hypothesis or "none", gap.exponent if gap.exponent is not None else math.nan)
        except MSAMError as error:
            diagnosed = (f"error: {error}", math.nan)
    return adapted, diagnosed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs=2, type=int, default=(1000, 1100), metavar=("FIRST", "STOP"))
    parser.add_argument("--family", choices=("drag", "power"), default="drag")
    parser.add_argument("--tolerance", type=float, default=0.05)
    parser.add_argument("--noise", type=float, default=NOISE, help="noise std as a share of the displacement's")
    parser.add_argument("--no-diagnose", action="store_true")
    parser.add_argument("--form", choices=("strong", "weak"), help="adaptation.form for adapt (default: the preset's)")
    args = parser.parse_args()
    hits = {"adapt": 0, "diagnose": 0}
    count = 0
    print("| seed | g | excitation | w_n | samples/period | adapt | diagnose |\n|---|---|---|---|---|---|---|")
    for seed in range(*args.seeds):
        case = draw(seed, args.family, args.noise)
        if args.form:
            case["config"]["adaptation"] = {"form": args.form}
        started = time.perf_counter()
        adapted, diagnosed = judged(case["config"], case["train"], case["held_out"], not args.no_diagnose)
        right = lambda found, prefix: found is not None and found[0].startswith(prefix) and \
            abs(found[1] - case["g"]) <= args.tolerance
        ok_adapt, ok_diagnose = right(adapted, "abs(x_dot)"), right(diagnosed, "x_dot")
        hits["adapt"] += ok_adapt
        hits["diagnose"] += ok_diagnose
        count += 1
        show = lambda found, ok: "-" if found is None else f"{found[0]} {found[1]:.3f} {'ok' if ok else 'WRONG'}"
        print(f"| {seed} | {case['g']:.3f} | {case['excitation']} | {case['wn']:.3g} | {case['per_period']:.0f} | "
              f"{show(adapted, ok_adapt)} | {show(diagnosed, ok_diagnose)} | <!-- {time.perf_counter() - started:.0f} s -->",
              flush=True)
    print(f"\nseeds {args.seeds[0]}-{args.seeds[1] - 1}, family {args.family}, noise {args.noise}, tolerance {args.tolerance}: "
          f"adapt {hits['adapt']}/{count}" + ("" if args.no_diagnose else f", diagnose {hits['diagnose']}/{count}"))


if __name__ == "__main__":
    main()
