"""The record's edges, where an equation's estimated derivative is unreliable: a local smoother
(``savgol``, ``loess``) fits its first and last windows one-sidedly there, and a zero-phase filter
(``butterworth``) starts up; the report's figures shade them and leave them out of the scaling of
their axes, so that their spikes do not hide the residual in between."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msam_torch.model.spec import split_derivative


@dataclass(frozen=True)
class Edges:
    """``width`` (time) at each end of the record; ``why``: what sets it."""

    width: float
    why: str

    def inside(self, t: np.ndarray) -> np.ndarray:
        """Which samples of ``t`` lie between the two edges."""
        return (t >= t[0] + self.width) & (t <= t[-1] - self.width)


def edges(estimator: dict, target: str, t: np.ndarray, times: str = "time units") -> Edges | None:
    """The edges of the one-step rows ``t`` of ``target``'s equation (None where its derivative
    was given or is estimated without a window or cut-off): half the smoother's window (samples of
    the record the derivatives were estimated on, before the weak form's ``refinement``), or a
    period at the filter's cut-off (``times``: how a time is written)."""
    found = estimator.get("derivatives")
    found = found.get(split_derivative(target)[0]) if isinstance(found, dict) else None
    if not found or t.size < 2:
        return None
    if found.get("window"):
        half = int(found["window"]) // 2
        width = half * max(1, int(estimator.get("refinement", 1) or 1)) * float(np.median(np.diff(t)))
        return Edges(width, f"half the {found['method']} window, {half} samples = {width:.3g} {times}")
    if found.get("cutoff"):
        width = 1.0 / float(found["cutoff"])
        return Edges(width, f"a period at the {found['method']} cut-off, {width:.3g} {times}")
    return None
