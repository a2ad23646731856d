"""Small copies of real benchmark records that ship with msam-torch (nothing is downloaded).

Each folder holds the data files and a README.md with the source, citation, terms and exactly what
was sliced from the full record (``experiments/realdata/make_datasets.py`` rebuilds them)::

    >>> from msam_torch import datasets
    >>> datasets.names()
    ['cascaded_tanks', 'emps', 'silverbox', 'us_macro']
    >>> frame = datasets.load("silverbox", "multisine")      # a pandas DataFrame
    >>> datasets.path("emps", "emps_estimation")             # the file, e.g. for a config's data.file

Configs in ``configs/`` point at these files with paths relative to the config file.
"""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from msam_torch.errors import DataError

ROOT = Path(__file__).resolve().parent
SUFFIXES = (".csv", ".csv.gz", ".parquet")


def names() -> list[str]:
    """The datasets carried in the package."""
    return sorted(p.name for p in ROOT.iterdir() if p.is_dir() and (p / "README.md").exists())


def files(name: str) -> list[str]:
    """The records of dataset ``name`` (file names without suffix)."""
    folder = _folder(name)
    return sorted(p.name[: -len(s)] for p in folder.iterdir() for s in SUFFIXES if p.name.endswith(s))


def path(name: str, record: str) -> Path:
    """The file of ``record`` in dataset ``name``."""
    folder = _folder(name)
    for suffix in SUFFIXES:
        candidate = folder / f"{record}{suffix}"
        if candidate.exists():
            return candidate
    raise DataError(f"dataset {name!r} has no record {record!r} (records: {', '.join(files(name))})")


def load(name: str, record: str) -> pd.DataFrame:
    """Record ``record`` of dataset ``name`` as a DataFrame (columns as described in its README)."""
    file = path(name, record)
    return pd.read_parquet(file) if file.suffix == ".parquet" else pd.read_csv(file)


def readme(name: str) -> str:
    """Source, citation, terms and slicing of dataset ``name``."""
    return (_folder(name) / "README.md").read_text()


def _folder(name: str) -> Path:
    folder = ROOT / name
    if not (folder / "README.md").exists():
        raise DataError(f"no dataset {name!r} (datasets: {', '.join(names())})")
    return folder
