"""Table 3: the third-order model, 10 trials per level, success rate per state equation.

    python -m experiments.paper.table3 [experiments/paper/table3.yaml] [--out DIR] [--max-trials K]
"""
from pathlib import Path

from experiments.common import arguments, main_guard
from experiments.paper.controlled import run_tables


def main() -> int:
    args = arguments("experiments/paper/table3.yaml", "experiments/results/table3", __doc__)
    return run_tables([Path(args.config)], Path(args.out), "table3", args.max_trials)


if __name__ == "__main__":
    main_guard(main)
