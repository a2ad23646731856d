"""Table 2: the harmonic and van der Pol oscillators, 10 trials at 0, 25 and 50 % parametric error.

    python -m experiments.paper.table2 [experiments/paper/table2_harmonic.yaml experiments/paper/table2_vanderpol.yaml]
        [--out DIR] [--max-trials K]
"""
import argparse
from pathlib import Path

from experiments.common import ROOT, main_guard, set_threads
from experiments.paper.controlled import run_tables


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("configs", nargs="*", default=[str(ROOT / "experiments/paper/table2_harmonic.yaml"),
                                                       str(ROOT / "experiments/paper/table2_vanderpol.yaml")])
    parser.add_argument("--out", default=str(ROOT / "experiments/results/table2"))
    parser.add_argument("--max-trials", type=int, default=None)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    set_threads(args.threads)
    return run_tables([Path(c) for c in args.configs], Path(args.out), "table2", args.max_trials)


if __name__ == "__main__":
    main_guard(main)
