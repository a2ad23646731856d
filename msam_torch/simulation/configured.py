"""Simulation set up from a config: the states compared with the data (``simulation.output``),
the states' ranges (``simulation.saturation``) and the records, built by the project's one loader
(:func:`msam_torch.data.loading.load_datasets`) from a config's file or system, a path, an in-memory
table (pandas DataFrame, mapping of arrays) or a :class:`~msam_torch.data.loading.Dataset`.

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
from msam_torch.data.derivatives import DerivativeEstimator
from msam_torch.data.information import check_simulation_record
from msam_torch.data.loading import Dataset, Table, resolve_datasets
from msam_torch.errors import ConfigError, DataError
from msam_torch.model.spec import ModelSpec, split_derivative
from msam_torch.simulation.ode import SystemModel
from msam_torch.simulation.record import Record


def output_states(config: Config, spec: ModelSpec, model: SystemModel) -> tuple[str, ...]:
    """The simulated states compared with the data (``simulation.output``, else the measured ones)."""
    sim = config.adaptation.simulation
    for i, name in enumerate(sim.output):
        if name not in spec.states:
            raise ConfigError(f"adaptation.simulation.output[{i}]", f"{name!r} is not a state of the model")
    chosen = tuple(o for o in sim.output if o in model.states)
    if not sim.output:
        chosen = tuple(s for s in model.states if s in config.data.columns)
    if not chosen:
        raise ConfigError("adaptation.simulation.output", f"name the measured states among {list(model.states)} "
                          "that the simulation is compared with")
    return chosen


def state_limits(config: Config, states: tuple[str, ...], dtype=torch.float64, device=None) -> torch.Tensor | None:
    """The range of every simulated state (2, S) from ``simulation.saturation`` (None: unbounded);
    ranges of states another group simulates are ignored."""
    saturation = config.adaptation.simulation.saturation
    if not saturation:
        return None
    for name, (low, high) in saturation.items():
        key = f"adaptation.simulation.saturation.{name}"
        if name not in config.model.states:
            raise ConfigError(key, f"{name!r} is not a state of the model")
        if low is not None and high is not None and not low < high:
            raise ConfigError(key, f"the range [{low}, {high}] is empty: give [low, high] with low < high")
    bound = lambda name, k, default: default if saturation.get(name, (None, None))[k] is None else float(saturation[name][k])
    return torch.tensor([[bound(x, 0, -torch.inf) for x in states], [bound(x, 1, torch.inf) for x in states]],
                        dtype=dtype, device=device)


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
