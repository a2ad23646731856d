"""Start-up benchmark: wall time of ``msam --help`` beside ``import torch``, in one run.

    python -m experiments.bench.bench_startup [--repeats 9]

Each command runs ``--repeats`` times as a fresh process, the commands interleaved so that a change
in the machine's load hits them alike; the median wall time of each is printed with its ratio to
``python -c "import torch"``. ``PYTHONPATH`` is set to this checkout, so ``python -m msam_torch`` and
the ``msam`` console script (timed when it is on PATH) both run this checkout's package. The bare
interpreter is the floor.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def commands() -> dict[str, list[str]]:
    found = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "python -m msam_torch --help": [sys.executable, "-m", "msam_torch", "--help"],
        "python -m msam_torch --version": [sys.executable, "-m", "msam_torch", "--version"],
    }
    script = shutil.which("msam")
    if script:
        found[f"msam --help ({script})"] = [script, "--help"]
    found['python -c "import torch"'] = [sys.executable, "-c", "import torch"]
    return found


def wall_time(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=9, help="runs of each command (median printed)")
    args = parser.parse_args()
    timed = commands()
    times: dict[str, list[float]] = {name: [] for name in timed}
    for name, command in timed.items():  # one untimed run each: file-system caches warm
        wall_time(command)
    for _ in range(args.repeats):
        for name, command in timed.items():
            times[name].append(wall_time(command))
    torch_median = statistics.median(times['python -c "import torch"'])
    print(f"median wall time of {args.repeats} runs each, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"{'command':<60} {'median s':>9} {'min s':>7} {'vs import torch':>16}")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:<60} {median:>9.3f} {min(values):>7.3f} {median / torch_median:>15.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
