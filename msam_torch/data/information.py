"""Records that carry no information are errors, never a fitted model: too few samples for the
values an equation fits, a target constant up to rounding, non-finite or unsquarable values, and
adjustment functions of constant magnitude.

:func:`check_variation` checks the signals of equations evaluated algebraically (their targets
derived from the data); :func:`check_simulation_record` those of a simulated group, whose measured
outputs take the targets' part in the fitness (the paper's section 2 alternative to Eq. 6).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import torch

from msam_torch.errors import DataError, Uninformative
from msam_torch.model.spec import Equation, ModelSpec


def check_variation(spec: ModelSpec, signals: Mapping[str, torch.Tensor], source: str,
                    derived: frozenset[str] = frozenset()) -> None:
    """Targets must vary (the fitness correlates with them, Eq. 19); so must every adjustment
    function's magnitude, or its exponent has nothing to act on. A target in ``derived`` (estimated
    by numerical differentiation) must vary beyond the half of the working precision such an
    estimate keeps."""
    for e, equation in enumerate(spec.equations):
        target = signals[equation.target]
        where = f"model.equations[{e}]"
        _enough_samples(target.shape[-1], [equation], where, source)
        _varies(target, f"the target {equation.target!r} of {where}", source, equation.target in derived)
        expressions = [(f"components[{i}].term", c.term) for i, c in enumerate(equation.components)]
        expressions += [(f"adjustments[{i}]", f) for i, f in enumerate(equation.adjustments)]
        for key, expression in [("target", None)] + expressions:
            value = target if expression is None else torch.as_tensor(expression(signals)).expand_as(target)
            name = repr(equation.target if expression is None else expression.text)
            _representable(value, f"{name} ({where}.{key})", source)
        for i, function in enumerate(equation.adjustments):
            _magnitude_varies(function, signals, target, f"{where}.adjustments[{i}]", source)


def check_simulation_record(equations: Sequence[Equation], outputs: Sequence[str], external: Sequence[str],
                            signals: Mapping[str, torch.Tensor], source: str) -> None:
    """A record for simulating ``equations``: enough samples for the values they fit, measured
    ``outputs`` that vary (the fitness of Eq. 19 correlates the simulated outputs with them),
    finite and squarable outputs and ``external`` signals, and adjustment functions that read
    only ``external`` signals (taken from the record as they are) of varying magnitude."""
    t = signals["t"]
    where = "model.equations[" + ", ".join(str(e) for e in range(len(equations))) + "]"
    _enough_samples(t.shape[-1], equations, f"the simulated {where}", source)
    for name in outputs:
        _varies(signals[name], f"the measured output {name!r}", source)
    for name in (*outputs, *external):
        _representable(signals[name], f"the signal {name!r}", source)
    for e, equation in enumerate(equations):
        for i, function in enumerate(equation.adjustments):
            if function.names <= set(external):
                _magnitude_varies(function, signals, t, f"model.equations[{e}].adjustments[{i}]", source)


def _enough_samples(samples: int, equations: Sequence[Equation], where: str, source: str) -> None:
    unknowns = sum(len(eq.components) + len(eq.adjustable) for eq in equations)
    if samples < unknowns + 2:
        raise DataError(f"{source}: {samples} samples for {where}, which fits {unknowns} "
                        f"values (theta and exponents); the fitness (Eq. 19) needs at least {unknowns + 2}")


def _varies(values: torch.Tensor, what: str, source: str, derived: bool = False) -> None:
    if _constant(values):
        raise Uninformative(f"{source}: {what} is constant up to rounding: the record tells nothing for it (the "
                            "fitness correlation, Eq. 19, needs it to vary)")
    spread = _relative_spread(values)
    if derived and spread <= torch.finfo(values.dtype).eps ** 0.5:
        raise Uninformative(f"{source}: {what}, estimated from the data, is constant to within the precision of the "
                            f"estimate (it varies by {spread:.2g} of its size; a derivative estimated from "
                            "samples keeps at most half the digits): the record tells nothing about which terms "
                            "the model misses")


def _representable(value: torch.Tensor, what: str, source: str) -> None:
    """Finite, and squarable without overflow or underflow."""
    bad = torch.nonzero(~torch.isfinite(value)).flatten()
    if bad.numel():
        raise DataError(f"{source}: {what} is not finite at {bad.numel()} samples (first at sample {int(bad[0])}, "
                        "0-based)")
    finfo, size = torch.finfo(value.dtype), float(value.abs().max())
    if 0 < size < finfo.tiny ** 0.5 or size > finfo.max ** 0.5:
        raise DataError(f"{source}: {what} reaches at most {size:.3g}, beyond what {value.dtype} can square "
                        f"({finfo.tiny ** 0.5:.2g} .. {finfo.max ** 0.5:.2g}): rescale the data")


def _magnitude_varies(function, signals: Mapping[str, torch.Tensor], like: torch.Tensor, key: str,
                      source: str) -> None:
    if _constant(torch.as_tensor(function(signals)).abs().expand_as(like)):
        raise DataError(f"{source}: adjustment function {function.text!r} ({key}) has constant magnitude on the "
                        "data, so its exponent cannot be identified")


def _relative_spread(values: torch.Tensor) -> float:
    """(max - min) / max |value| (0 for values that are all 0)."""
    size = float(values.abs().max())
    return float(values.max() - values.min()) / size if size > 0 else 0.0


def _constant(values: torch.Tensor) -> bool:
    """Constant up to rounding: the spread is within what summing the samples (N eps) leaves."""
    return _relative_spread(values) <= values.shape[-1] * torch.finfo(values.dtype).eps
