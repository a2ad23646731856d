"""The measured-data preset against the paper's step on records nobody tuned it to.

For each case ``adapt`` runs twice on the same noisy training frame: ``preset=paper`` (the literal
step, Savitzky-Golay derivatives, nominal theta fixed; what a frame got before) and the default
(``auto``: the ``measured`` preset). Printed: the adapted equation and the free-run R^2 on the
held-out frame (``MSAM.score``). Cases: the quadratic-drag oscillator of tests/run/test_estimator.py
under three excitations, withheld-effect cases of ``msam_torch.data.systems.WITHHELD`` (0.5 % noise),
and zoo cases from seeds that no test or figure uses (their ``derivatives`` key dropped, so the
preset chooses).

    python -m experiments.suites.measured_preset [--zoo 5000 5010]
"""
from __future__ import annotations

import argparse
import copy
import math
import time

import numpy as np
import pandas as pd
import torch

from msam_torch import MSAM, MSAMError
from msam_torch.data.systems import SYSTEMS, WITHHELD, System, measure, multisine

DRAG = {"m": 2.0, "c": 3.0, "k": 20.0}
DRAG_MODEL = {"states": ["x", "x_dot"], "inputs": ["u"], "parameters": DRAG,
              "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-c/m"},
                                                               {"term": "x", "theta": "-k/m"},
                                                               {"term": "u", "theta": "1/m", "adjustable": False}],
                             "adjustments": ["abs(x_dot)", "abs(x)"]}]}
EXCITATIONS = {"A": ((0.4, 0.7, 1.1, 1.5, 1.9, 2.4, 3.0, 3.7), 10.0), "B": ((1, 2, 3, 4, 5), 4.0),
               "C": ((0.5, 1, 2, 3, 4, 6, 8), 20.0)}
WITHHELD_CASES = ("msd_quadratic_drag", "msd_hardening", "msd_power_damping", "msd_coulomb")


def _drag(t, s, p, u):
    x, v = s[..., 0], s[..., 1]
    return torch.stack([v, (-p["c"] * v * v.abs() - p["k"] * x + u["u"]) / p["m"]], -1)


def noisy(system: System, noise: float = 0.005, seed: int = 0) -> pd.DataFrame:
    s = {k: v.numpy() for k, v in measure(system).items()}
    rng = np.random.default_rng(seed)
    out = {"time": s["t"]}
    for k in system.measured:
        out[k] = s[k] if k in system.inputs else s[k] + noise * s[k].std() * rng.standard_normal(s[k].size)
    return pd.DataFrame(out)


def cases(zoo_seeds):
    columns = {"time": "time", "columns": {"x": "x", "u": "u"}}
    for name, (frequencies, amplitude) in EXCITATIONS.items():
        make = lambda f, a, seed: noisy(System(("x", "x_dot"), DRAG, _drag, (0.0, 0.0), 40.0, 2000,
                                               {"u": multisine(f, a)}, ("x", "u")), seed=seed)
        yield f"drag {name}", {"model": DRAG_MODEL, "data": columns}, make(frequencies, amplitude, 0), \
            make((0.5, 0.9, 1.3, 1.7, 2.2, 2.8), 8.0, 1)
    for name in WITHHELD_CASES:
        w = WITHHELD[name]
        yield name, {"model": w.model, "data": columns}, noisy(SYSTEMS[w.system]), noisy(SYSTEMS[w.held_out], seed=1)
    if zoo_seeds:
        from msam_torch.zoo import generate

        for seed in range(*zoo_seeds):
            case = generate(seed)
            config = copy.deepcopy(case.config)
            for key in ("derivatives", "file", "validation_file"):
                config["data"].pop(key, None)
            yield f"zoo {seed} ({case.metadata['system']}, {case.truth.get('name')})", config, case.train, case.validation


def run(config, train, held, preset):
    options = {} if preset == "auto" else {"preset": preset}
    try:
        estimator = MSAM(config, **options).fit(train)
        return estimator.equations(), estimator.score(held)
    except MSAMError as error:
        return [f"error: {error}"], -math.inf


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--zoo", nargs=2, type=int, default=(5000, 5006), metavar=("FIRST", "STOP"),
                        help="zoo seeds [FIRST, STOP)")
    args = parser.parse_args()
    print("| case | paper: adapted | R^2 | measured preset: adapted | R^2 |\n|---|---|---|---|---|")
    for name, config, train, held in cases(args.zoo):
        started = time.perf_counter()
        (paper, paper_r2), (preset, preset_r2) = (run(config, train, held, p) for p in ("paper", "auto"))
        print(f"| {name} | {'; '.join(paper)} | {paper_r2:.4f} | {'; '.join(preset)} | {preset_r2:.4f} |"
              f" <!-- {time.perf_counter() - started:.0f} s -->", flush=True)


if __name__ == "__main__":
    main()
