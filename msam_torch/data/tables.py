"""Tables in: a CSV or Parquet file (rows indexed by their line in the file), or an in-memory table
(a pandas DataFrame, or a mapping of equal-length 1-D arrays or tensors), as a DataFrame that the
data loader (:mod:`msam_torch.data.loading`) reads its columns from."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Union

import numpy as np
import pandas as pd
import torch

from msam_torch.errors import DataError

Table = Union[pd.DataFrame, Mapping[str, object]]


def as_frame(data: Table, source: str) -> tuple[pd.DataFrame, str]:
    """A DataFrame from a DataFrame or a mapping of equal-length 1-D arrays or tensors."""
    if isinstance(data, pd.DataFrame):
        frame = data.reset_index(drop=True)
    elif isinstance(data, Mapping):
        columns = {}
        for name, value in data.items():
            array = value.detach().cpu().numpy() if torch.is_tensor(value) else np.asarray(value)
            if array.ndim != 1:
                raise DataError(f"{source}: column {name!r} must be 1-D, got shape {array.shape}")
            columns[str(name)] = array
        if len({a.size for a in columns.values()}) > 1:
            sizes = {k: a.size for k, a in columns.items()}
            raise DataError(f"{source}: columns differ in length {sizes}")
        frame = pd.DataFrame(columns)
    else:
        raise DataError(f"{source}: expected a pandas DataFrame or a mapping of column name to array, "
                        f"got {type(data).__name__}")
    frame.index.name = "row"
    return frame, source


def read_frame(path: Path, folder: Path | None = None, key: str | None = None) -> tuple[pd.DataFrame, str]:
    """Read a CSV or Parquet file (named by the config's ``key``). CSV rows are indexed by their line in the file; unnamed
    empty columns (trailing commas) are dropped. Error messages list the file's column names only
    when it lies inside ``folder`` (the config's): nothing of a file elsewhere is ever echoed."""
    source = str(path)
    if not path.is_file():
        raise DataError(f"{source}: no such data file" + (f" ({key})" if key else ""))
    parquet = path.suffix.lower() in (".parquet", ".pq")
    try:
        if parquet:
            frame = pd.read_parquet(path)
            frame = frame.reset_index(drop=True)
            frame.index.name = "row"
        else:
            frame = pd.read_csv(path, comment="#", skipinitialspace=True)
            lines = _data_lines(path)
            if len(lines) == len(frame):  # else (quoted line breaks) fall back to 0-based rows
                frame.index = lines
            frame.index.name = "line" if len(lines) == len(frame) else "row"
    except (DataError, MemoryError):
        raise
    except Exception as exc:  # pandas and pyarrow raise many types for unreadable files
        kind = "Parquet" if parquet else "CSV"
        raise DataError(f"{source}: cannot read as {kind}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    keep = [c for c in frame.columns if not (str(c).startswith("Unnamed") and frame[c].isna().all())]
    frame = frame.loc[:, keep]
    frame.attrs["private"] = folder is None or not path.resolve().is_relative_to(Path(folder).resolve())
    return frame, source


def _data_lines(path: Path) -> list[int]:
    """1-based line numbers of a CSV file's data rows (blank and comment lines skipped)."""
    lines = []
    with open(path, errors="replace") as handle:
        for number, line in enumerate(handle, 1):
            if line.strip() and not line.lstrip().startswith("#"):
                lines.append(number)
    return lines[1:]  # the first is the header
