"""Results as values: the adapted equation in the paper's notation and ``result.json``.

``result.json`` schema (documented in the README):
``{"version": 1, "config": {...resolved config...}, "data": {...provenance...},
"equations": [EquationResult.to_dict(), ...]}``.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from .candidates import FLOOR
from .outputs import write_atomic
from .spec import Equation


def _number(value: float) -> str:
    return f"{value:.4g}"


def format_component(equation: Equation, index: int, function: int | None, gamma: float | None) -> str:
    """``x_dot|x_dot|^1.000`` (magnitude) or ``x1 sgn(x3)|x3|^1.000`` (signed); unadjusted: ``u``."""
    term = equation.components[index].term.text
    if any(op in term for op in "+-"):  # a sum reads as one factor: (c + i + g)|y|^0.5
        term = f"({term})"
    if function is None:
        return term
    f = equation.adjustments[function]
    inner = f.inner_text
    inner = inner if inner.isidentifier() else f"({inner})"
    adjustment = f"|{inner}|^{gamma:.3f}" if f.is_magnitude else f"sgn({inner})|{inner}|^{gamma:.3f}"
    return f"{term}{adjustment}" if term.isidentifier() and f.is_magnitude else f"{term} {adjustment}"


def format_equation(target: str, thetas: list[float], terms: list[str]) -> str:
    """``x_ddot = -26.13 x_dot|x_dot|^1.000 - 346.7 x|x|^2.000 + 0.002667 u``."""
    parts = []
    for theta, term in zip(thetas, terms):
        sign = "-" if theta < 0 else "+"
        body = f"{_number(abs(theta))} {term}"
        parts.append(f"{sign} {body}" if parts else (f"-{body}" if theta < 0 else body))
    return f"{target} = " + " ".join(parts)


def adjusted_columns(equation: Equation, entry, signals: dict) -> torch.Tensor:
    """The components of ``entry`` (an :class:`EquationResult` or anything with its ``adjustments``
    and ``exponents``) with their adjustments ``M_i f_i^gamma_i`` (Eq. 9), without theta: (N, Q)."""
    functions = {f.text: f for f in equation.adjustments}
    target = signals[equation.target]
    cols = []
    for i, component in enumerate(equation.components):
        term = torch.as_tensor(component.term(signals), dtype=target.dtype).expand_as(target)
        if entry.adjustments[i] is not None:
            function = functions[entry.adjustments[i]]
            f = function(signals)
            magnitude = f.abs().clamp_min(FLOOR) ** entry.exponents[i]
            term = term * (magnitude if function.is_magnitude else torch.sign(f) * magnitude)
        cols.append(term)
    return torch.stack(cols, -1)


@dataclass(frozen=True)
class EquationResult:
    """The outcome for one state equation (one trial).

    ``adjustments``: per component, the selected function text or null (fixed component);
    ``exponents``: per component, the final gamma or null; ``theta``: final theta per component;
    ``start``, ``final``: ``fitness``, ``sum_abs_error``, ``rho``;
    ``ranking``: every candidate with its adjustments and best round-robin fitness, best first;
    ``diverged``: number of candidates marked diverged and skipped;
    ``theta_tuning``: theta re-estimated by least squares for the starting and for the adapted
    model (``start``/``final``: ``equation``, ``theta``, measures and ``nominal_error``, the
    relative distance of each nominal theta from the tuned one), ``used_for_start``, ``hold_fixed``;
    ``validation``: measures on held-out data of ``start``, ``start_tuned``, ``final``, ``final_tuned``.
    """

    target: str
    equation: str
    start_equation: str
    adjustments: list
    exponents: list
    theta: list
    start: dict
    final: dict
    ranking: list
    diverged: int
    theta_tuning: dict = field(default_factory=dict)
    validation: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RunResult:
    """All state equations of a run; ``str()`` prints the adapted equations."""

    equations: list[EquationResult]
    config: dict
    data: dict

    def __str__(self) -> str:
        return "\n".join(e.equation for e in self.equations)

    def to_dict(self) -> dict:
        return {"version": 1, "config": self.config, "data": self.data,
                "equations": [e.to_dict() for e in self.equations]}

    def save(self, path: str | Path) -> Path:
        """Write JSON atomically (temporary file, then rename)."""
        return write_atomic(path, json.dumps(_finite(self.to_dict()), indent=2))


def _finite(value):
    """JSON has no inf/nan: write them as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
