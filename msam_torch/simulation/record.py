"""Measured records for simulation: time, external signals (inputs, states read from the data)
and the measured outputs on a uniform grid, built by the project's one loader
(:func:`msam_torch.data.loading.load_datasets`) from a config's file or system, a path, an in-memory table
(pandas DataFrame, mapping of arrays) or a :class:`~msam_torch.data.loading.Dataset`.

Measured signals enter the record as measured (no smoothing); a simulated state that is not
measured starts from ``simulation.initial_guess``, else from the configured derivative estimator
applied to a measured lower derivative (``x_dot`` from ``x``), else from 0.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from msam_torch.config.schema import Config
from msam_torch.data.loading import Dataset, Table, resolve_datasets
from msam_torch.signals.derivatives import DerivativeEstimator
from msam_torch.errors import DataError
from msam_torch.data.information import check_simulation_record
from msam_torch.model.spec import ModelSpec, split_derivative
from msam_torch.simulation.ode import SystemModel


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


@dataclass(frozen=True)
class RecordSpec(ModelSpec):
    """The signals a record holds, as a :class:`ModelSpec` for the loader: ``inputs`` are taken
    as measured, ``states`` are estimated from a measured lower derivative."""

    names: frozenset = frozenset()

    @property
    def signals(self) -> frozenset[str]:
        return self.names


def load_records(config: Config, spec: ModelSpec, model: SystemModel, outputs: tuple[str, ...], base_dir: Path,
                 dtype=torch.float64, data: Table | Dataset | str | Path | None = None,
                 validation: Table | Dataset | str | Path | None = None,
                 estimator: DerivativeEstimator | None = None) -> tuple[Record, Record | None]:
    """Training and (if configured or given) validation records for ``model``; ``data`` and
    ``validation`` replace the config's data source as in :func:`msam_torch.data.loading.resolve_datasets`,
    states that start from a measured lower derivative estimated with ``estimator``."""
    sim = config.adaptation.simulation
    measured = set(config.data.columns) if config.data.system is None and not isinstance(data, Dataset) else set()
    raw = tuple(dict.fromkeys(list(model.external) + list(outputs) + sorted(measured & spec.signals)))
    estimated = tuple(s for s in model.states if s not in raw and s not in sim.initial_guess and any(
        split_derivative(m)[0] == split_derivative(s)[0] and split_derivative(m)[1] < split_derivative(s)[1]
        for m in raw))
    record_spec = RecordSpec(estimated, raw, {}, (), frozenset(raw + estimated + ("t",)))
    train, held_out = resolve_datasets(config.data, record_spec, base_dir, dtype, data, validation, estimator)
    record = lambda dataset: _record(dataset, model, outputs, raw, sim.initial_guess, sim.input_hold, dtype)
    return record(train), None if held_out is None else record(held_out)


def _record(dataset: Dataset, model: SystemModel, outputs, raw, initial_guess, hold: str, dtype) -> Record:
    signals = dataset.signals
    missing = [n for n in raw if n not in signals]
    if missing:
        raise DataError(f"{dataset.info.get('source', 'data')}: simulation needs the signals {missing} "
                        f"(it has {sorted(set(signals) - {'t'})})")
    check_simulation_record(model.equations, outputs, model.external, signals, dataset.info.get("source", "data"))
    as_tensor = lambda v: torch.as_tensor(np.asarray(v, dtype=float).copy(), dtype=dtype)
    first = lambda s: float(signals[s][0]) if s in raw or (s in signals and s not in initial_guess) \
        else float(initial_guess.get(s, 0.0))
    guess = [first(s) for s in model.states]
    t = as_tensor(signals["t"])
    external = torch.stack([as_tensor(signals[n]) for n in model.external], -1) if model.external \
        else torch.zeros(t.shape[0], 0, dtype=dtype)
    return Record.build(t, external, torch.stack([as_tensor(signals[o]) for o in outputs]),
                        torch.tensor(guess, dtype=dtype), hold)
