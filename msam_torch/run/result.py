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

from msam_torch.engine.candidates import FLOOR
from msam_torch.model.spec import Equation
from msam_torch.run.outputs import write_atomic
from msam_torch.run.state_model import StateModel


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
    ``start``, ``adapted``: ``fitness``, ``sum_abs_error``, ``rho``;
    ``ranking``: every candidate with its adjustments and best round-robin fitness, best first;
    ``diverged``: number of candidates marked diverged and skipped;
    ``theta_tuning``: theta re-estimated by least squares for the starting and for the adapted
    model (``retuned``/``adapted_retuned``: ``equation``, ``theta``, measures and ``nominal_error``, the
    relative distance of each nominal theta from the tuned one), ``used_for_start``, ``hold_fixed``;
    ``validation``: measures on held-out data of ``start``, ``retuned``, ``adapted``, ``adapted_retuned``.
    """

    target: str
    equation: str
    start_equation: str
    adjustments: list
    exponents: list
    theta: list
    start: dict
    adapted: dict
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

    def model(self, stage: str = "adapted", dtype=torch.float64):
        """The state equations of ``stage`` (``start``, ``retuned``, ``adapted``, ``adapted_retuned``)
        as an ``nn.Module`` ``f(t, x)`` (:class:`~msam_torch.run.state_model.StateModel`)."""
        return StateModel.from_result(self, stage, dtype)

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
