"""The noise-floor window rule (:func:`msam_torch.data.derivatives.choose_window`) against the best fixed
Savitzky-Golay window in hindsight: on the bundled harmonic oscillator and van der Pol (x, second
derivative) and third-order system (x1, x2, x3, first derivative), at 0.1, 1 and 5 % noise, seeds 0
and 1, the RMS error of the highest derivative with the chosen window over the least error of the
windows 5, 9, ..., 401; prints each case and the range and median of the ratio.

    python -m experiments.suites.window_rule
"""
from __future__ import annotations

import numpy as np

from msam_torch.data.derivatives import estimate
from msam_torch.data.systems import SYSTEMS, measure

CASES = (("harmonic", (("x", 2),)), ("vanderpol", (("x", 2),)), ("sode3", (("x1", 1), ("x2", 1), ("x3", 1))))
NOISE = (0.001, 0.01, 0.05)
SEEDS = (0, 1)
GRID = range(5, 402, 4)


def main() -> None:
    ratios = []
    print("| system | signal | noise | seed | chosen window | error / best fixed window's |")
    print("|---|---|---|---|---|---|")
    for name, signals in CASES:
        s = {k: v.numpy() for k, v in measure(SYSTEMS[name]).items()}
        for key, order in signals:
            target = s[key + ("_ddot" if order == 2 else "_dot")]
            for noise in NOISE:
                for seed in SEEDS:
                    y = s[key] + noise * s[key].std() * np.random.default_rng(seed).standard_normal(s[key].size)
                    error = lambda w: np.sqrt(np.mean((estimate(s["t"], y, order, "savgol", w).values[order] - target) ** 2))
                    window = estimate(s["t"], y, order, "savgol").info["window"]
                    ratios.append(error(window) / min(error(w) for w in GRID if w < y.size))
                    print(f"| {name} | {key} | {100 * noise:g} % | {seed} | {window} | {ratios[-1]:.2f} |")
    print(f"\nratio {min(ratios):.2f}-{max(ratios):.2f}, median {np.median(ratios):.2f} ({len(ratios)} cases)")


if __name__ == "__main__":
    main()
