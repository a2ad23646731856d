"""Measured records for simulation: time, external signals (inputs, states read from the data)
and the measured outputs on a uniform grid (:class:`Record`); built from a config's data by
:func:`msam_torch.simulation.configured.load_records`."""
from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class Record:
    """A record on a uniform grid: time (N,), external signals (N, E) or per row (B, N, E),
    measured outputs (O, N) and initial-state guesses (S,)."""

    t: torch.Tensor
    external: torch.Tensor
    outputs: torch.Tensor
    guess: torch.Tensor
    hold: str = "linear"
    pieces: torch.Tensor | None = None  # (N-1, 4, E) cubic interpolating spline of ``external`` (hold "cubic")
    held: torch.Tensor | None = None  # (E,) bool: signals held between samples whatever ``hold`` (a stepped input)

    @classmethod
    def build(cls, t: torch.Tensor, external: torch.Tensor, outputs: torch.Tensor, guess: torch.Tensor,
              hold: str = "linear") -> "Record":
        """A record; ``hold: cubic`` fits the not-a-knot cubic spline through the external samples
        (the band-limited signal between samples, which linear interpolation attenuates near the
        Nyquist frequency)."""
        pieces = None
        if hold == "cubic" and external.shape[-1]:
            from scipy.interpolate import CubicSpline

            spline = CubicSpline(t.cpu().numpy(), external.cpu().numpy(), axis=0)
            pieces = torch.as_tensor(spline.c, dtype=external.dtype, device=external.device).movedim(0, 1)
        return cls(t, external, outputs, guess, hold, pieces)

    def to(self, device) -> "Record":
        move = lambda v: None if v is None else v.to(device)
        return Record(move(self.t), move(self.external), move(self.outputs), move(self.guess), self.hold, move(self.pieces),
                      move(self.held))

    def at(self, t: torch.Tensor) -> torch.Tensor:
        """External signals at times ``t`` (M,) -> (M, E) or (B, M, E): linear interpolation,
        zero-order hold or cubic spline (the ``held`` signals held)."""
        n = self.t.shape[0]
        step = self.t[1] - self.t[0]
        position = (t - self.t[0]) / step
        zoh = lambda: self.external[..., torch.floor(position + 1e-9).long().clamp(0, n - 1), :]
        if self.hold == "zoh":
            return zoh()
        k = torch.floor(position).long().clamp(0, n - 2)
        if self.pieces is not None:
            s, c = ((position - k) * step).unsqueeze(-1), self.pieces[k].movedim(-2, 0)
            values = ((c[0] * s + c[1]) * s + c[2]) * s + c[3]
        else:
            w = (position - k).clamp(0.0, 1.0).unsqueeze(-1)
            values = self.external[..., k, :] * (1 - w) + self.external[..., k + 1, :] * w
        return values if self.held is None or not bool(self.held.any()) else torch.where(self.held, zoh(), values)
