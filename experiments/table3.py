"""Table 3: the third-order model, 10 trials per level, success rate per state equation.

    PYTHONPATH=. python experiments/table3.py [configs/table3.yaml] [--out DIR] [--max-trials K]
"""
from pathlib import Path

from experiments.common import arguments, main_guard
from experiments.controlled import run_tables


def main() -> int:
    args = arguments("configs/table3.yaml", "experiments/results/table3", __doc__)
    return run_tables([Path(args.config)], Path(args.out), "table3", args.max_trials)


if __name__ == "__main__":
    main_guard(main)
