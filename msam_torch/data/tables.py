"""Tables in: a CSV or Parquet file (rows labelled by their line in the file), or an in-memory table
(a pandas DataFrame, or a mapping of equal-length 1-D arrays or tensors), as a :class:`Table` of
numeric columns that the data loader (:mod:`msam_torch.data.loading`) reads.

A CSV file, plain or compressed by gzip, bzip2 or xz, is read with the csv module and NumPy, as
pandas reads it with ``comment='#'`` and ``skipinitialspace=True`` (pandas' import alone costs a
fifth of a second of a diagnosis from the shell); Parquet files, CSV files in other archives
(``.zip``, ``.zst``, ``.tar``) and DataFrames are read with pandas. Every cell is a number, missing (empty,
NaN or one of pandas' missing-value words) or not a number, so that the loader names the rows of
each kind.
"""
from __future__ import annotations

import bz2
import csv
import gzip
import io
import lzma
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from msam_torch.errors import DataError

NUMBER, MISSING, TEXT = 0, 1, 2  # what a cell holds (Table.kinds)
MISSING_WORDS = frozenset({"", "#N/A", "#N/A N/A", "#NA", "-1.#IND", "-1.#QNAN", "-NaN", "-nan", "1.#IND", "1.#QNAN",
                           "<NA>", "N/A", "NA", "NULL", "NaN", "None", "n/a", "nan", "null"})  # pandas' na_values
OPENERS = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}  # compressed CSV files read as text
ARCHIVES = (".zip", ".zst", ".tar")  # CSV files pandas unpacks


@dataclass(frozen=True)
class Table:
    """Numeric columns of equal length (``values``: NaN where a cell is not a number; ``kinds``:
    :data:`NUMBER`, :data:`MISSING` or :data:`TEXT` per cell) with each row's label (``labels``,
    named ``label``: ``line`` for a CSV file's line, else the 0-based ``row``); ``private``: the
    table comes from a file outside the config's folder, whose column names are never echoed."""

    values: dict[str, np.ndarray]
    kinds: dict[str, np.ndarray]
    labels: np.ndarray
    label: str = "row"
    private: bool = False

    def __len__(self) -> int:
        return self.labels.size

    def rows(self, keep: np.ndarray) -> Table:
        """The rows where ``keep`` holds, with their labels."""
        return replace(self, values={k: v[keep] for k, v in self.values.items()},
                       kinds={k: v[keep] for k, v in self.kinds.items()}, labels=self.labels[keep])


def is_frame(data: Any) -> bool:
    """Whether ``data`` is a pandas DataFrame (without importing pandas: no DataFrame exists before it is)."""
    pandas = sys.modules.get("pandas")
    return pandas is not None and isinstance(data, pandas.DataFrame)


def as_table(data: Any, source: str) -> tuple[Table, str]:
    """A :class:`Table` from a DataFrame or a mapping of equal-length 1-D arrays or tensors."""
    if is_frame(data):
        return _from_frame(data.reset_index(drop=True)), source
    if not isinstance(data, Mapping):
        raise DataError(f"{source}: expected a pandas DataFrame or a mapping of column name to array, "
                        f"got {type(data).__name__}")
    columns = {}
    for name, value in data.items():
        array = value.detach().cpu().numpy() if torch.is_tensor(value) else np.asarray(value)
        if array.ndim != 1:
            raise DataError(f"{source}: column {name!r} must be 1-D, got shape {array.shape}")
        columns[str(name)] = array
    if len({a.size for a in columns.values()}) > 1:
        sizes = {k: a.size for k, a in columns.items()}
        raise DataError(f"{source}: columns differ in length {sizes}")
    size = next(iter(columns.values())).size if columns else 0
    return _table(columns, np.arange(size)), source


def read_table(path: Path, folder: Path | None = None, key: str | None = None) -> tuple[Table, str]:
    """Read a CSV or Parquet file (named by the config's ``key``). CSV rows are labelled by their line in the file; unnamed
    empty columns (trailing commas) are dropped. Error messages list the file's column names only
    when it lies inside ``folder`` (the config's): nothing of a file elsewhere is ever echoed."""
    source = str(path)
    if not path.is_file():
        raise DataError(f"{source}: no such data file" + (f" ({key})" if key else ""))
    parquet, suffix = path.suffix.lower() in (".parquet", ".pq"), path.suffix.lower()
    try:
        if parquet or suffix in ARCHIVES:
            import pandas as pd

            frame = pd.read_parquet(path) if parquet else pd.read_csv(path, comment="#", skipinitialspace=True)
            table = _from_frame(frame.reset_index(drop=True))
        else:
            table = _read_csv(path, OPENERS.get(suffix, open))
    except (DataError, MemoryError):
        raise
    except Exception as exc:  # pandas, pyarrow and the csv module raise many types for unreadable files
        kind = "Parquet" if parquet else "CSV"
        raise DataError(f"{source}: cannot read as {kind}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    keep = [c for c in table.values if not (c.startswith("Unnamed") and (table.kinds[c] == MISSING).all())]
    private = folder is None or not path.resolve().is_relative_to(Path(folder).resolve())
    return replace(table, values={c: table.values[c] for c in keep}, kinds={c: table.kinds[c] for c in keep},
                   private=private), source


def _read_csv(path: Path, opener=open) -> Table:
    """The cells of a CSV file under its header: blank lines and lines starting with ``#`` skipped,
    the rest of a line after ``#`` ignored, spaces after a delimiter skipped; rows are labelled by
    their line (0-based rows where a quoted cell spans lines); a short row is filled with missing
    cells, a long one is an error."""
    with opener(path, "rt", newline="", errors="replace") as handle:
        lines = [(number, line.split("#", 1)[0]) for number, line in enumerate(handle, 1)
                 if line.strip() and not line.lstrip().startswith("#")]
    rows = list(csv.reader(io.StringIO("".join(text if text.endswith("\n") else text + "\n" for _, text in lines)),
                           skipinitialspace=True))
    rows = [row for row in rows if row]
    if not rows:
        raise ValueError("No columns to parse from file")
    header, body = rows[0], rows[1:]
    names = _unique([name or f"Unnamed: {k}" for k, name in enumerate(header)])
    for k, row in enumerate(body):
        if len(row) > len(names):
            raise ValueError(f"Error tokenizing data. Expected {len(names)} fields in row {k + 2}, saw {len(row)}")
    cells = [row + [""] * (len(names) - len(row)) for row in body]
    columns = {name: np.array([row[j] for row in cells], dtype=object) for j, name in enumerate(names)}
    numbered = len(lines) == len(rows)  # else a quoted cell spans lines
    labels = np.array([number for number, _ in lines[1:]]) if numbered else np.arange(len(body))
    return _table(columns, labels, "line" if numbered else "row")


def _unique(names: list[str]) -> list[str]:
    """Repeated column names made unique as pandas does (``x``, ``x.1``, ...)."""
    seen, out = {}, []
    for name in names:
        count = seen.get(name, 0)
        seen[name] = count + 1
        out.append(name if count == 0 else f"{name}.{count}")
    return out


def _from_frame(frame) -> Table:
    """A DataFrame's columns through ``pandas.to_numeric(errors='coerce')``; missing where ``isna``."""
    import pandas as pd

    values, kinds = {}, {}
    for name in frame.columns:
        raw = frame[name]
        values[str(name)] = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
        missing = raw.isna().to_numpy()
        kinds[str(name)] = np.where(missing, MISSING, np.where(np.isnan(values[str(name)]), TEXT, NUMBER))
    return Table(values, kinds, np.arange(len(frame)))


def _table(columns: dict[str, np.ndarray], labels: np.ndarray, label: str = "row") -> Table:
    values, kinds = {}, {}
    for name, array in columns.items():
        values[name], kinds[name] = _numbers(array)
    return Table(values, kinds, labels, label)


def _numbers(array: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The values of a column as floats (NaN where not a number) and what each cell holds."""
    try:  # every cell a number (NaN: missing)
        values = array.astype(float)
        return values, np.where(np.isnan(values), MISSING, NUMBER).astype(np.int8)
    except (TypeError, ValueError):
        pass
    values, kinds = np.full(array.size, np.nan), np.full(array.size, NUMBER, dtype=np.int8)
    for k, cell in enumerate(array):
        if cell is None or (isinstance(cell, float) and math.isnan(cell)) or (isinstance(cell, str) and cell.strip() in MISSING_WORDS):
            kinds[k] = MISSING
            continue
        try:
            values[k] = float(cell)
        except (TypeError, ValueError):
            kinds[k] = TEXT
    return values, kinds
