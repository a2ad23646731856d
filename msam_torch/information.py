"""Records that carry no information are errors, never a fitted model: too few samples for the
values an equation fits, a target constant up to rounding, non-finite or unsquarable values, and
adjustment functions of constant magnitude."""
from __future__ import annotations

from typing import Mapping

import torch

from .errors import DataError
from .spec import ModelSpec


def check_variation(spec: ModelSpec, signals: Mapping[str, torch.Tensor], source: str) -> None:
    """Targets must vary (the fitness correlates with them, Eq. 19); so must every adjustment
    function's magnitude, or its exponent has nothing to act on."""
    for e, equation in enumerate(spec.equations):
        target = signals[equation.target]
        unknowns = len(equation.components) + len(equation.adjustable)
        if target.shape[-1] < unknowns + 2:
            raise DataError(f"{source}: {target.shape[-1]} samples for model.equations[{e}], which fits {unknowns} "
                            f"values (theta and exponents); the fitness (Eq. 19) needs at least {unknowns + 2}")
        if _constant(target):
            raise DataError(f"{source}: the target {equation.target!r} of model.equations[{e}] is constant up to "
                            "rounding: the fitness correlation (Eq. 19) needs it to vary")
        expressions = [(f"components[{i}].term", c.term) for i, c in enumerate(equation.components)]
        expressions += [(f"adjustments[{i}]", f) for i, f in enumerate(equation.adjustments)]
        for key, expression in [("target", None)] + expressions:
            value = target if expression is None else torch.as_tensor(expression(signals)).expand_as(target)
            bad = torch.nonzero(~torch.isfinite(value)).flatten()
            name = repr(equation.target if expression is None else expression.text)
            if bad.numel():
                raise DataError(f"{source}: {name} (model.equations[{e}].{key}) is not finite at "
                                f"{bad.numel()} samples (first at sample {int(bad[0])}, 0-based)")
            finfo, size = torch.finfo(value.dtype), float(value.abs().max())
            if 0 < size < finfo.tiny ** 0.5 or size > finfo.max ** 0.5:
                raise DataError(f"{source}: {name} (model.equations[{e}].{key}) reaches at most {size:.3g}, beyond "
                                f"what {value.dtype} can square ({finfo.tiny ** 0.5:.2g} .. {finfo.max ** 0.5:.2g}): "
                                "rescale the data")
        for i, function in enumerate(equation.adjustments):
            magnitude = torch.as_tensor(function(signals)).abs().expand_as(target)
            if _constant(magnitude):
                raise DataError(f"{source}: adjustment function {function.text!r} (model.equations[{e}]"
                                f".adjustments[{i}]) has constant magnitude on the data, so its exponent "
                                "cannot be identified")


def _constant(values: torch.Tensor) -> bool:
    """Constant up to rounding: the spread is within what summing the samples (N eps) leaves."""
    spread, size = float(values.max() - values.min()), float(values.abs().max())
    return spread <= values.shape[-1] * torch.finfo(values.dtype).eps * size
