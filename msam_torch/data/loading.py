"""Measurements in: the signals every equation reads, from a simulated system, a data file
(CSV or Parquet) or an in-memory table (pandas DataFrame, or a mapping of arrays or tensors).

A *signal* is a 1-D tensor over the samples: states, inputs, their time derivatives and ``t``.
Signals the model reads but the data do not hold are estimated from the measured signal of the
same base name (``x_ddot`` from ``x`` or ``x_dot``) with :mod:`msam_torch.data.derivatives`; measured
states are replaced by their smoothed estimate at the same time, so regressors and targets share
one filter. Every check names the place: the file (or table), the column, the row (the file's
line for CSV files, the 0-based row otherwise) and the config key.
"""
from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Union

import numpy as np
import torch

from msam_torch.config.schema import DataConfig, RangeConfig
from msam_torch.data.bandwidth import RESOLVED, decimate, oversampling
from msam_torch.data.derivatives import ESTIMATORS, Auto, DerivativeEstimator, Exact, configured, noise_level, takes
from msam_torch.data.information import check_variation
from msam_torch.data.systems import get_system, measure
from msam_torch.data.tables import MISSING, TEXT, Table, as_table, is_frame, read_table
from msam_torch.errors import ConfigError, DataError
from msam_torch.model.spec import ModelSpec, split_derivative

if TYPE_CHECKING:
    import pandas

REGULAR = 1e-2  # sampling is regular when every step is within 1 % of the median step
LARGEST = float(np.finfo(np.float64).max) / 8  # a measured value at most this large keeps third differences finite


@dataclass(frozen=True)
class Dataset:
    """Signals on a common time base and how they were obtained."""

    signals: dict[str, torch.Tensor]
    info: dict = field(default_factory=dict)
    measured: dict[str, torch.Tensor] = field(default_factory=dict)  # as recorded, unsmoothed (empty: ``signals``)

    @property
    def t(self) -> torch.Tensor:
        return self.signals["t"]


def derivative_estimator(config: DataConfig, in_memory: bool = False) -> DerivativeEstimator:
    """The estimator of ``data.derivatives`` (a registered name or an estimator object) with
    ``data.window`` and ``data.cutoff`` set; ``auto`` chosen for the record (exact for a noise-free
    simulated system, unless the data are given ``in_memory``). The one reader of these keys."""
    chosen = ESTIMATORS.resolve(config.derivatives)
    if isinstance(chosen, Auto):
        chosen = chosen.choose(not in_memory and config.system is not None and config.noise == 0)
    if config.cutoff is not None and not takes(chosen, "cutoff"):
        with_cutoff = [n for n in ESTIMATORS.names if takes(ESTIMATORS.create(n), "cutoff")]
        raise ConfigError("data.cutoff", f"a cut-off applies to derivatives: {', '.join(with_cutoff)}, not {chosen.name!r}")
    return configured(chosen, config.window, config.cutoff)


DataArgument = Union[str, Path, Mapping, "pandas.DataFrame", Dataset, None]


def load_datasets(config: DataConfig, spec: ModelSpec, base_dir: Path | str = ".", dtype=torch.float64,
                  frame=None, validation_frame=None,
                  estimator: DerivativeEstimator | None = None,
                  keys: tuple[str, str] = ("data.file", "data.validation_file")) -> tuple[Dataset, Dataset | None]:
    """Training and (if configured) validation datasets for ``spec``.

    ``frame`` (and ``validation_frame``) replace ``data.file`` (``data.validation_file``) with an
    in-memory table (``keys``: what a missing file is named by); the column mapping, time and ranges still come from ``config``, the
    derivative ``estimator`` too unless given (:func:`derivative_estimator`)."""
    if frame is None and (config.system is None) == (config.file is None):
        raise ConfigError("data", "give exactly one of 'system' (simulated) or 'file' (measured)")
    estimator = derivative_estimator(config, frame is not None) if estimator is None else estimator
    if frame is None and config.system is not None:
        return simulated_dataset(config, spec, dtype, estimator), None
    base_dir = Path(base_dir)
    table, source = (as_table(frame, "data frame") if frame is not None
                     else read_table(base_dir / config.file, base_dir, keys[0]))
    train = measured_dataset(select_range(table, config.train, config, source, "data.train"),
                             config, spec, f"{source} (data.train)", dtype, estimator)
    validation, period = None, train.info["sample_time"]  # held out at the training record's (decimated) rate
    if validation_frame is not None or config.validation_file is not None:
        held, held_source = (as_table(validation_frame, "validation frame") if validation_frame is not None
                             else read_table(base_dir / config.validation_file, base_dir, keys[1]))
        validation = measured_dataset(held, config, spec, held_source, dtype, estimator, period)
    elif config.validation is not None:
        part = select_range(table, config.validation, config, source, "data.validation")
        validation = measured_dataset(part, config, spec, f"{source} (data.validation)", dtype, estimator, period)
    return train, validation


def resolve_datasets(config: DataConfig, spec: ModelSpec, base_dir: Path | str = ".", dtype=torch.float64,
                     data: DataArgument = None, validation: DataArgument = None,
                     estimator: DerivativeEstimator | None = None) -> tuple[Dataset, Dataset | None]:
    """Training and held-out datasets from the data arguments of ``adapt`` and ``diagnose``.

    ``data`` replaces the record of ``data.file``/``data.system``: a CSV/Parquet path (relative
    to the working directory), a pandas DataFrame or a mapping of column to 1-D array or tensor
    (read through ``config``: columns, time, the ``train`` and ``validation`` ranges, estimator),
    or a :class:`Dataset` (used as it is, nothing held out). ``validation`` replaces the held-out
    record (the ``validation`` range or ``validation_file``) in the same forms, read whole.
    Default (None): the config's own. ``estimator`` as in :func:`load_datasets`."""
    for key, value in (("data", data), ("validation", validation)):
        if value is not None and not (isinstance(value, (str, Path, Mapping, Dataset)) or is_frame(value)):
            raise DataError(f"{key}: expected a CSV/Parquet path, a pandas DataFrame, a mapping of column name to "
                            f"array or a Dataset, got {type(value).__name__}")
    read_whole = validation is not None and not isinstance(validation, Dataset)
    if isinstance(data, Dataset):
        if read_whole:
            raise DataError("validation: with data given as a Dataset, give the held-out data as a Dataset too")
        return data, validation
    if read_whole and data is None and config.system is not None:
        raise DataError("validation: held-out data from a file or table need measured training data "
                        f"(data.file or the data argument), not the simulated system {config.system!r}")
    update = {}
    if isinstance(data, (str, Path)):
        update.update(file=str(Path(data).resolve()), system=None)
    if isinstance(validation, (str, Path)):
        update.update(validation_file=str(Path(validation).resolve()), validation=None)
    frame = data if isinstance(data, Mapping) or is_frame(data) else None
    validation_frame = validation if isinstance(validation, Mapping) or is_frame(validation) else None
    keys = ("the data argument" if "file" in update else "data.file",
            "the validation argument" if "validation_file" in update else "data.validation_file")
    train, held_out = load_datasets(config.model_copy(update=update), spec, base_dir, dtype, frame,
                                    validation_frame, estimator, keys)
    return train, validation if isinstance(validation, Dataset) else held_out


def _rows(frame: Table, positions: np.ndarray, limit: int = 5) -> str:
    label = frame.label
    shown = ", ".join(str(frame.labels[int(i)]) for i in positions[:limit])
    return f"{label}{'s' if positions.size > 1 else ''} {shown}{' ...' if positions.size > limit else ''}"


def column(frame: Table, name: str, source: str, key: str) -> np.ndarray:
    """A numeric column without NaN, inf or values whose differences (up to the third, 8 times the
    largest magnitude) leave the float range; errors name the file, column, rows and config key."""
    if name not in frame.values:
        names = list(frame.values)
        lower = {n.lower(): n for n in names}
        close = difflib.get_close_matches(str(name).lower(), list(lower), n=1)
        hint = f"; did you mean {lower[close[0]]!r}?" if close else ""
        listing = "" if frame.private else f"; columns are {names}{hint}"
        raise DataError(f"{source}: no column {name!r} (asked for by {key}){listing}")
    values, kinds = frame.values[name], frame.kinds[name]
    for bad, what in ((kinds == MISSING, "missing or NaN"),
                      (kinds == TEXT, "non-numeric"),
                      (np.isinf(values), "infinite")):
        positions = np.flatnonzero(bad)
        if positions.size:
            raise DataError(f"{source}: column {name!r} ({key}) has {positions.size} {what} value"
                            f"{'s' if positions.size > 1 else ''} at {_rows(frame, positions)}")
    huge = np.flatnonzero(np.abs(values) > LARGEST)
    if huge.size:
        raise DataError(f"{source}: column {name!r} ({key}) has values beyond +-{LARGEST:.3g} at "
                        f"{_rows(frame, huge)}, whose differences leave the float range; rescale the column")
    return values


def time_axis(frame: Table, config: DataConfig, source: str) -> np.ndarray:
    if config.time is not None:
        return column(frame, config.time, source, "data.time")
    if config.sample_time is None:
        raise ConfigError("data.time", "give a time column ('time') or a sampling period ('sample_time')")
    return np.arange(len(frame)) * config.sample_time


def select_range(frame: Table, rng: RangeConfig, config: DataConfig, source: str, key: str) -> Table:
    """Rows of ``frame`` in ``rng`` (inclusive bounds, by time or 0-based sample index)."""
    if len(frame) == 0:
        raise DataError(f"{source}: the table has no rows")
    axis = np.arange(len(frame)) if rng.by == "index" else time_axis(frame, config, source)
    keep = np.ones(len(frame), dtype=bool)
    if rng.start is not None:
        keep &= axis >= rng.start
    if rng.stop is not None:
        keep &= axis <= rng.stop
    if not keep.any():
        span = f"{axis.min():.6g} to {axis.max():.6g}" if axis.size else "nothing"
        raise ConfigError(key, f"the range [{rng.start}, {rng.stop}] by {rng.by} selects no samples of "
                               f"{source} (its {rng.by} runs from {span})")
    return frame.rows(keep)


def measured_dataset(frame: Table, config: DataConfig, spec: ModelSpec, source: str, dtype,
                     estimator: DerivativeEstimator | None = None, period: float | None = None) -> Dataset:
    """Signals of ``spec`` from a table: time checks, column mapping, resampling, decimation of
    an oversampled record (to about the sample time ``period``, default: chosen from its band,
    :func:`decimate_oversampled`), estimation (``estimator``: default :func:`derivative_estimator`
    of ``config``)."""
    estimator = derivative_estimator(config, True) if estimator is None else estimator
    if len(frame) < 2:
        raise DataError(f"{source}: {len(frame)} sample{'s' if len(frame) != 1 else ''}; need at least 2")
    t = time_axis(frame, config, source)
    bases = {split_derivative(s)[0] for s in spec.signals}
    measured = {}
    for signal, name in config.columns.items():
        if signal not in spec.signals and split_derivative(signal)[0] not in bases:
            raise ConfigError(f"data.columns.{signal}", f"{signal!r} is not a signal of the model "
                                                        f"(signals: {', '.join(sorted(spec.signals - {'t'}))})")
        measured[signal] = column(frame, name, source, f"data.columns.{signal}")
    info = {"source": source}
    estimated = not isinstance(estimator, Exact)
    t, measured, info = decimate_oversampled(*check_time(frame, t, measured, source, config, estimated, info), period)
    try:
        return build_dataset(t, measured, config, spec, info, dtype, source, estimator)
    except DataError as error:
        if "decimated" not in info:
            raise
        raise DataError(f"after decimation by {info['decimated']['factor']}: {error}") from None


def decimate_oversampled(t: np.ndarray, measured: dict, info: dict,
                         period: float | None = None) -> tuple[np.ndarray, dict, dict]:
    """A record on a uniform grid sampled far faster than its band, low-pass filtered and
    decimated (by :func:`~msam_torch.data.bandwidth.oversampling`'s factor, or to about the sample time
    ``period``: a held-out record at the training record's rate, whatever its own) before anything
    else reads it; ``info['decimated']`` records how. Irregular grids stay as they are."""
    dt = info["sample_time"]
    if t.size < 3 or np.abs(np.diff(t) - dt).max() > REGULAR * dt:
        return t, measured, info
    band = None
    if period is None:
        every, band = oversampling(measured)
    else:
        every = max(1, round(period / dt))
    if every == 1:
        return t, measured, info
    kept = t[::every]
    rule = (f"at least {RESOLVED} samples per period of the band edge {band / dt:.4g} cycles per time unit"
            if band is not None else "the training record's")
    return kept, {k: decimate(v, every) for k, v in measured.items()}, {
        **info, "sample_time": dt * every,
        "decimated": {"from": int(t.size), "to": int(kept.size), "factor": every, "rule": rule}}


def check_time(frame: Table, t: np.ndarray, measured: dict, source: str, config: DataConfig,
               estimated: bool, info: dict) -> tuple[np.ndarray, dict, dict]:
    """Strictly increasing time; a uniform grid where derivatives are estimated (or resampled)."""
    steps = np.diff(t)
    where = "time column " + repr(config.time) if config.time else "time"
    duplicated = np.flatnonzero(steps == 0)
    if duplicated.size:
        raise DataError(f"{source}: {where} has duplicated values ({float(t[duplicated[0]]):g}) at "
                        f"{_rows(frame, duplicated + 1)}; remove or average the duplicates")
    backwards = np.flatnonzero(steps < 0)
    if backwards.size:
        raise DataError(f"{source}: {where} is not increasing at {_rows(frame, backwards + 1)} "
                        f"({float(t[backwards[0]]):g} then {float(t[backwards[0] + 1]):g}); sort the data by time")
    median = float(np.median(steps))
    irregular = np.flatnonzero(np.abs(steps - median) > REGULAR * median)
    if not irregular.size or not estimated:
        return t, measured, {**info, "sample_time": median}
    if not config.resample:
        raise DataError(f"{source}: irregular sampling in {where} (median step {median:.6g}, but steps "
                        f"from {steps.min():.6g} to {steps.max():.6g}, first at {_rows(frame, irregular + 1)}); "
                        f"the derivative estimators need a uniform grid: set data.resample=true to interpolate "
                        f"linearly onto one, or resample the data yourself")
    grid = t[0] + median * np.arange(int(np.floor((t[-1] - t[0]) / median + 1e-9)) + 1)
    resampled = {k: np.interp(grid, t, v) for k, v in measured.items()}
    return grid, resampled, {**info, "sample_time": median,
                             "resampled": {"from": int(t.size), "to": int(grid.size), "method": "linear"}}


def build_dataset(t: np.ndarray, measured: dict[str, np.ndarray], config: DataConfig, spec: ModelSpec,
                  info: dict, dtype, source: str = "data", estimator: DerivativeEstimator | None = None,
                  keep_measured: bool = False) -> Dataset:
    """Estimate every signal ``spec`` reads, and every state the measured ones give (free runs start
    from each state), from the measured ones (``estimator``: default
    :func:`derivative_estimator` of ``config``; measured states smoothed by it unless
    ``keep_measured``), then check they vary where the method needs variation (targets for the
    correlation of Eq. 19, adjustment functions)."""
    estimator = derivative_estimator(config, True) if estimator is None else estimator
    exact = isinstance(estimator, Exact)
    signals = {"t": t}
    estimates = {}
    source_of = lambda name: sorted((split_derivative(m)[1], m) for m in measured
                                    if split_derivative(m)[0] == split_derivative(name)[0]
                                    and split_derivative(m)[1] <= split_derivative(name)[1])
    # every signal the equations read, and every state the data give (a free run starts from each state)
    wanted = spec.signals | {s for s in spec.states if s in measured or (source_of(s) and not exact)}
    for name in sorted(wanted - {"t"}):
        if name in measured and (exact or keep_measured or name in spec.inputs):
            signals[name] = measured[name]
            continue
        base, order = split_derivative(name)
        sources = source_of(name)
        if not sources:
            raise ConfigError("data.columns", f"the model reads {name!r} but no measured column gives {base!r} "
                              f"or a lower derivative of it (measured: {', '.join(sorted(measured)) or 'none'})")
        measured_order, source_name = sources[-1]
        if exact:
            raise ConfigError("data.derivatives", f"{name!r} is not measured: choose an estimator "
                              f"({', '.join(n for n in ESTIMATORS.names if n != estimator.name)})")
        if source_name not in estimates:
            highest = max(split_derivative(s)[1] for s in wanted if split_derivative(s)[0] == base) - measured_order
            column_name = config.columns.get(source_name, source_name)
            estimates[source_name] = estimator.estimate(t, measured[source_name], highest,
                                                        f"{source}: column {column_name!r} ({source_name})")
        signals[name] = estimates[source_name].values[order - measured_order]
    info = {**info, "samples": int(t.size), "measured": sorted(measured),
            "derivatives": {k: e.info for k, e in estimates.items()} or estimator.name,
            "noise_level": {k: noise_level(v) for k, v in measured.items()}}
    tensors = {k: torch.tensor(np.asarray(v, dtype=float), dtype=dtype) for k, v in signals.items()}
    check_variation(spec, tensors, source, frozenset(signals) - frozenset(measured))
    return Dataset(tensors, info, {k: torch.tensor(np.asarray(v, dtype=float), dtype=dtype) for k, v in measured.items()})


@functools.lru_cache(maxsize=8)
def _simulation(name: str) -> dict[str, np.ndarray]:
    """The noise-free simulation of a named system (computed once per process)."""
    return {k: v.numpy() for k, v in measure(get_system(name), dtype=torch.float64).items()}


def simulated_measurements(config: DataConfig) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """A controlled case: every simulated signal, and what its sensors record (with noise)."""
    system = get_system(config.system)
    simulated = {k: v.copy() for k, v in _simulation(config.system).items()}
    rng = np.random.default_rng(config.seed)
    measured = {}
    for name in system.measured:
        value = simulated[name]
        noisy = name not in system.inputs and config.noise > 0
        measured[name] = value + config.noise * value.std() * rng.standard_normal(value.size) if noisy else value
    return simulated, measured


def simulated_dataset(config: DataConfig, spec: ModelSpec, dtype, estimator: DerivativeEstimator) -> Dataset:
    """A controlled case: simulate the true system, add noise to its measured signals, estimate."""
    simulated, measured = simulated_measurements(config)
    missing = sorted(spec.signals - set(simulated))
    if missing:
        raise ConfigError("model", f"system {config.system!r} has no signals {missing} (it has {sorted(simulated)})")
    info = {"source": f"system:{config.system}", "noise": config.noise, "seed": config.seed}
    if isinstance(estimator, Exact) and config.noise == 0:
        signals = {k: torch.as_tensor(v, dtype=dtype) for k, v in simulated.items()}
        check_variation(spec, signals, info["source"])
        return Dataset(signals, {**info, "samples": int(simulated["t"].size), "derivatives": estimator.name})
    if isinstance(estimator, Exact):
        raise ConfigError("data.derivatives", "with noise, derivatives must be estimated: choose one of "
                          f"{', '.join(n for n in ESTIMATORS.names if n != estimator.name)}")
    return build_dataset(simulated["t"], measured, config, spec, info, dtype, info["source"], estimator)
