"""Property tests (issue 18): any expression text and any ``key=value`` override either gives a
value or raises :class:`~msam_torch.errors.MSAMError`, never another exception.
``python -m experiments.suites.input_properties`` runs this file with ``MSAM_PROPERTY_EXAMPLES`` set
(10^4 examples of each kind)."""
from __future__ import annotations

import math
import os

import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.errors import ConfigError, MSAMError
from msam_torch.model.expressions import FUNCTIONS, parse
from tests.helpers import CONFIGS

NAMES = ("c", "m", "x")
EXAMPLES = int(os.environ.get("MSAM_PROPERTY_EXAMPLES", "150"))  # the experiment asks for more
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
KEYS = ["data.seed", "data.noise", "data.window", "data.parametric_error", "data.derivatives", "data.train.start",
        "model.parameters.m", "model.parameters.c", "model.states", "adaptation.device", "adaptation.damping",
        "adaptation.round_robin_steps", "adaptation.step_size", "adaptation.simulation.initial_guess.x",
        "adaptation.simulation.saturation.x", "model", "data", "adaptation.gamma_limit"]

numbers = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from(["0", "1e308", "1e-320", "9" * 400, "0.0"]))
leaves = st.one_of(numbers.map(str), st.sampled_from(NAMES))
structured = st.recursive(leaves, lambda inner: st.one_of(
    st.tuples(inner, st.sampled_from(["+", "-", "*", "/", "**", "^"]), inner).map(lambda t: f"({t[0]} {t[1]} {t[2]})"),
    st.tuples(st.sampled_from(sorted(FUNCTIONS)), inner).map(lambda t: f"{t[0]}({t[1]})"),
    inner.map(lambda t: f"-{t}")), max_leaves=12)
expressions = st.one_of(structured, st.text(max_size=60),
                        st.text(alphabet="()+-*/^.,0123456789emxc abslogqrt_[]{}:'\"", max_size=80))
values = st.fixed_dictionaries({n: st.one_of(st.floats(allow_nan=False), st.integers(-3, 3)) for n in NAMES})
yaml_values = st.one_of(st.text(max_size=40), numbers.map(str), st.sampled_from(
    ["[", "{", "[" * 200, "{a: 1, a: 2}", "!!python/name:os.system", "&a [*a]", "*b", ".inf", "-.nan", "~", "null",
     "[1, 2]", "{x: 1}", "true", "cuda", "cuda:3", "-1", str(2**64), "1e8", "''"]))
overrides = st.tuples(st.one_of(st.sampled_from(KEYS), st.text(max_size=30)), yaml_values).map(lambda t: f"{t[0]}={t[1]}")


def check_expression(text: str, names: dict) -> None:
    """Parse and evaluate on numbers and on a tensor: a value, or ConfigError only."""
    try:
        expression = parse(text, "key", set(NAMES))
    except ConfigError:
        return
    for given_values in (names, {**names, "x": torch.linspace(-2, 2, 5, dtype=torch.float64)}):
        try:
            value = expression(given_values)
        except ConfigError as exc:
            assert str(exc).startswith("key: ") and "\n" not in str(exc)
            continue
        if not torch.is_tensor(value) or value.dim() == 0:
            assert math.isfinite(float(value))


def check_override(item: str) -> None:
    """An override on the bundled harmonic config loads (and its theta evaluates) or raises MSAMError."""
    try:
        config = load_config(CONFIGS / "harmonic.yaml", [item])
        spec = to_spec(config.model)
        for equation in spec.equations:
            assert torch.isfinite(spec.theta(equation)).all()
    except MSAMError as exc:
        assert "\n" not in str(exc)


@SETTINGS
@given(expressions, values)
def test_expressions_parse_and_evaluate_or_raise_config_errors(text, names):
    check_expression(text, names)


@SETTINGS
@given(overrides)
def test_overrides_load_or_raise_msam_errors(item):
    check_override(item)
