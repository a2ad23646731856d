"""The property checks of tests/data/test_input_properties.py on many examples (issue 18, acceptance 2):
generated expressions (parsed and evaluated) and ``key=value`` overrides (loaded, theta evaluated),
``--examples`` of each kind.

The experiments do not import the tests: the test file runs under pytest in a child process with
``MSAM_PROPERTY_EXAMPLES`` set. Hypothesis's statistics print how many examples each check ran; a
check that meets anything but the package's own errors fails with its smallest failing example (and
this script exits with pytest's status).

    python -m experiments.suites.input_properties [--examples 10000]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = "tests/data/test_input_properties.py"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=10_000, help="examples of each kind")
    args = parser.parse_args()
    if args.examples < 1:
        parser.error(f"--examples: at least 1, not {args.examples}")
    env = {**os.environ, "MSAM_PROPERTY_EXAMPLES": str(args.examples)}
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=",
               "--hypothesis-show-statistics", TESTS]
    return subprocess.run(command, cwd=ROOT, env=env, check=False).returncode


if __name__ == "__main__":
    sys.exit(main())
