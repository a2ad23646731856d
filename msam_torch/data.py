"""Measurements in: the signals every equation reads, from a simulated system or a data file.

A *signal* is a 1-D tensor over the samples: states, inputs, their time derivatives and ``t``.
Signals the model reads but the data do not hold are estimated from the measured signal of the
same base name (``x_ddot`` from ``x`` or ``x_dot``) with :mod:`msam_torch.derivatives`; measured
states are replaced by their smoothed estimate at the same time, so regressors and targets share
one filter.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from .config import DataConfig, RangeConfig
from .derivatives import estimate, noise_level
from .errors import ConfigError, DataError
from .spec import ModelSpec, derivative_name, split_derivative
from .systems import get_system, simulate


@dataclass(frozen=True)
class Dataset:
    """Signals on a common time base and how they were obtained."""

    signals: dict[str, torch.Tensor]
    info: dict = field(default_factory=dict)

    @property
    def t(self) -> torch.Tensor:
        return self.signals["t"]


def load_datasets(config: DataConfig, spec: ModelSpec, base_dir: Path | str = ".", dtype=torch.float64,
                  ) -> tuple[Dataset, Dataset | None]:
    """Training and (if configured) validation datasets for ``spec``."""
    if (config.system is None) == (config.file is None):
        raise ConfigError("data", "give exactly one of 'system' (simulated) or 'file' (measured)")
    if config.system is not None:
        return simulated_dataset(config, spec, dtype), None
    base_dir = Path(base_dir)
    frame, source = read_frame(base_dir / config.file)
    train = measured_dataset(select_range(frame, config.train, config, source, "data.train"), config, spec, source, dtype)
    validation = None
    if config.validation_file is not None:
        frame, source = read_frame(base_dir / config.validation_file)
        validation = measured_dataset(frame, config, spec, source, dtype)
    elif config.validation is not None:
        part = select_range(frame, config.validation, config, source, "data.validation")
        validation = measured_dataset(part, config, spec, source, dtype)
    return train, validation


def read_frame(path: Path) -> tuple[pd.DataFrame, str]:
    """Read a CSV or Parquet file; unnamed empty columns (trailing commas) are dropped."""
    source = str(path)
    if not path.exists():
        raise DataError(f"{source}: no such data file")
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            frame = pd.read_parquet(path)
        else:
            frame = pd.read_csv(path, comment="#", skipinitialspace=True)
    except Exception as exc:  # pandas raises many types for unreadable files
        raise DataError(f"{source}: cannot read as {'Parquet' if path.suffix.lower() in ('.parquet', '.pq') else 'CSV'}: {exc}") from None
    frame = frame.loc[:, [c for c in frame.columns if not (str(c).startswith("Unnamed") and frame[c].isna().all())]]
    return frame, source


def time_axis(frame: pd.DataFrame, config: DataConfig, source: str) -> np.ndarray:
    if config.time is not None:
        return column(frame, config.time, source, "data.time")
    if config.sample_time is None:
        raise ConfigError("data", "give a 'time' column or a 'sample_time'")
    return np.arange(len(frame)) * config.sample_time


def column(frame: pd.DataFrame, name: str, source: str, key: str) -> np.ndarray:
    """A numeric column without NaN or inf; errors name the file, column and rows."""
    if name not in frame.columns:
        raise DataError(f"{source}: no column {name!r} (for {key}); columns are {list(map(str, frame.columns))}")
    values = pd.to_numeric(frame[name], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        rows = ", ".join(str(int(frame.index[i]) + 2) for i in bad[:5]) + (" ..." if bad.size > 5 else "")
        raise DataError(f"{source}: column {name!r} has {bad.size} missing, non-numeric, NaN or inf values "
                        f"(file rows {rows}, counting the header as row 1)")
    return values


def select_range(frame: pd.DataFrame, rng: RangeConfig, config: DataConfig, source: str, key: str) -> pd.DataFrame:
    axis = np.arange(len(frame)) if rng.by == "index" else time_axis(frame, config, source)
    keep = np.ones(len(frame), dtype=bool)
    if rng.start is not None:
        keep &= axis >= rng.start
    if rng.stop is not None:
        keep &= axis <= rng.stop
    if not keep.any():
        raise ConfigError(key, f"the range [{rng.start}, {rng.stop}] by {rng.by} selects no samples of {source}")
    return frame.loc[keep]


def measured_dataset(frame: pd.DataFrame, config: DataConfig, spec: ModelSpec, source: str, dtype) -> Dataset:
    t = time_axis(frame, config, source)
    check_time(t, source)
    measured = {}
    for signal, name in config.columns.items():
        if signal not in spec.signals and split_derivative(signal)[0] not in {split_derivative(s)[0] for s in spec.signals}:
            raise ConfigError(f"data.columns.{signal}", f"{signal!r} is not a signal of the model")
        measured[signal] = column(frame, name, source, f"data.columns.{signal}")
    return build_dataset(t, measured, config, spec, {"source": source}, dtype)


def check_time(t: np.ndarray, source: str) -> None:
    steps = np.diff(t)
    if (steps <= 0).any():
        i = int(np.flatnonzero(steps <= 0)[0])
        raise DataError(f"{source}: time is not strictly increasing at file row {i + 3} "
                        f"({t[i]!r} then {t[i + 1]!r}); sort the file or remove duplicated times")
    if steps.size and (steps.max() - steps.min()) > 1e-6 * np.median(steps):
        raise DataError(f"{source}: irregular sampling (steps from {steps.min():.6g} to {steps.max():.6g}); "
                        "resample to a uniform grid first, e.g. frame.set_index(time).resample(...).interpolate()")


def build_dataset(t: np.ndarray, measured: dict[str, np.ndarray], config: DataConfig, spec: ModelSpec,
                  info: dict, dtype) -> Dataset:
    """Estimate every signal ``spec`` reads from the measured ones."""
    signals = {"t": t}
    estimates = {}
    for name in sorted(spec.signals - {"t"}):
        if name in measured and (config.derivatives == "exact" or name in spec.inputs):
            signals[name] = measured[name]
            continue
        base, order = split_derivative(name)
        sources = sorted((split_derivative(m)[1], m) for m in measured if split_derivative(m)[0] == base
                         and split_derivative(m)[1] <= order)
        if not sources:
            raise ConfigError("data.columns", f"the model reads {name!r} but no measured column gives {base!r} "
                              f"or a lower derivative of it")
        measured_order, source_name = sources[-1]
        if config.derivatives == "exact":
            raise ConfigError("data.derivatives", f"{name!r} is not measured: choose an estimator "
                              "(savgol, spline, loess or finite_difference)")
        need = order - measured_order
        key = (source_name,)
        if key not in estimates:
            highest = max(split_derivative(s)[1] for s in spec.signals if split_derivative(s)[0] == base) - measured_order
            estimates[key] = estimate(t, measured[source_name], highest, config.derivatives, config.window, source_name)
        signals[name] = estimates[key].values[need]
    for name in spec.signals - set(signals):
        raise ConfigError("data.columns", f"the model reads {name!r}, which the data do not give")
    info = {**info, "samples": int(t.size), "measured": sorted(measured),
            "derivatives": {k[0]: e.info for k, e in estimates.items()} or config.derivatives,
            "noise_level": {k: noise_level(v) for k, v in measured.items()}}
    return Dataset({k: torch.as_tensor(np.asarray(v), dtype=dtype) for k, v in signals.items()}, info)


def simulated_measurements(config: DataConfig) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """A controlled case: every simulated signal, and what its sensors record (with noise)."""
    system = get_system(config.system)
    simulated = {k: v.numpy() for k, v in simulate(system, dtype=torch.float64).items()}
    rng = np.random.default_rng(config.seed)
    measured = {}
    for name in system.measured:
        value = simulated[name]
        noisy = name not in system.inputs and config.noise > 0
        measured[name] = value + config.noise * value.std() * rng.standard_normal(value.size) if noisy else value
    return simulated, measured


def simulated_dataset(config: DataConfig, spec: ModelSpec, dtype) -> Dataset:
    """A controlled case: simulate the true system, add noise to its measured signals, estimate."""
    simulated, measured = simulated_measurements(config)
    missing = sorted(spec.signals - set(simulated))
    if missing:
        raise ConfigError("model", f"system {config.system!r} has no signals {missing} (it has {sorted(simulated)})")
    info = {"source": f"system:{config.system}", "noise": config.noise}
    if config.derivatives == "exact" and config.noise == 0:
        signals = {k: torch.as_tensor(v, dtype=dtype) for k, v in simulated.items()}
        return Dataset(signals, {**info, "samples": int(simulated["t"].size), "derivatives": "exact"})
    if config.derivatives == "exact":
        raise ConfigError("data.derivatives", "with noise, derivatives must be estimated: choose savgol, spline, "
                          "loess or finite_difference")
    return build_dataset(simulated["t"], measured, config, spec, info, dtype)
