"""The property checks of tests/test_input_properties.py on many examples (issue 18, acceptance 2):
generated expressions (parsed and evaluated) and ``key=value`` overrides (loaded, theta evaluated);
prints how many raised anything but the package's own errors.

    PYTHONPATH=. python experiments/input_properties.py [--examples 10000]
"""
from __future__ import annotations

import argparse
import collections

from hypothesis import HealthCheck, given, settings

from tests.data.test_input_properties import check_expression, check_override, expressions, overrides, values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=10_000, help="examples of each kind")
    args = parser.parse_args()
    run = settings(max_examples=args.examples, deadline=None, database=None,
                   suppress_health_check=list(HealthCheck))
    counts, unexpected = collections.Counter(), collections.Counter()

    def record(kind, check, *example):
        counts[kind] += 1
        try:
            check(*example)
        except Exception as exc:  # the checks let the package's own errors through; count the rest
            unexpected[(kind, type(exc).__name__, str(exc)[:80])] += 1

    run(given(expressions, values)(lambda text, names: record("expression", check_expression, text, names)))()
    run(given(overrides)(lambda item: record("override", check_override, item)))()
    for kind in ("expression", "override"):
        print(f"{kind}s generated: {counts[kind]}, unexpected exceptions: "
              f"{sum(n for (k, *_), n in unexpected.items() if k == kind)}")
    for (kind, name, message), n in unexpected.most_common(10):
        print(f"  {kind}: {name}: {message} (x{n})")


if __name__ == "__main__":
    main()
