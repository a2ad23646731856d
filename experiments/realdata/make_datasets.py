"""Build the small dataset copies under ``msam_torch/data/datasets/`` from the full benchmark files.

Run once, from the repository root, with the full data at ``SOURCE`` (default ``../shared/data``):

    python -m experiments.realdata.make_datasets [SOURCE]

Every slice is stated in the dataset's README.md; values are written unchanged (CSV, 9 significant
digits for the derived columns), gzip-compressed, with an explicit time column.
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pandas as pd

TARGET = Path(__file__).resolve().parents[2] / "msam_torch" / "data" / "datasets"

SILVERBOX_FS = 1e7 / 2**14  # Hz
SILVERBOX_SLICES = {  # file -> (first row, stop row) of SNLS80mV.csv, 0-based, stop exclusive
    "multisine.csv.gz": (40_600, 58_000),  # the first two odd-multisine realisations (estimation part)
    "arrow_tail.csv.gz": (30_000, 40_500),  # high-amplitude end of the filtered-noise "arrow" (test part)
    "train_multisine.csv.gz": (40_650, 105_712),  # nonlinear-benchmarks Silverbox(): training split
    "test_arrow.csv.gz": (100, 40_575),  # nonlinear-benchmarks Silverbox(): test_arrow_full
}


def read(path: Path) -> pd.DataFrame:
    frame = pd.read_csv(path)
    return frame.loc[:, [c for c in frame.columns if not str(c).startswith("Unnamed")]]


def write(frame: pd.DataFrame, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False, float_format="%.9g", compression={"method": "gzip", "mtime": 0})


def silverbox(source: Path) -> None:
    frame = read(source / "silverbox" / "SNLS80mV.csv")
    for name, (start, stop) in SILVERBOX_SLICES.items():
        part = frame.iloc[start:stop]
        out = pd.DataFrame({"sample": part.index, "t_s": part.index / SILVERBOX_FS, "V1": part.V1, "V2": part.V2})
        write(out, TARGET / "silverbox" / name)


def emps(source: Path) -> None:
    for name in ("emps_estimation", "emps_validation_pulses"):
        frame = read(source / "emps" / f"{name}.csv")
        write(frame[["t_s", "qm_m", "force_N"]], TARGET / "emps" / f"{name}.csv.gz")


def cascaded_tanks(source: Path) -> None:
    """The estimation and test records of dataBenchmark.csv as two files with the same columns."""
    frame = read(source / "cascaded_tanks" / "dataBenchmark.csv")
    sample_time = float(frame.Ts.iloc[0])
    for name, (u, y) in {"estimation.csv": ("uEst", "yEst"), "validation.csv": ("uVal", "yVal")}.items():
        out = pd.DataFrame({"t_s": frame.index * sample_time, "u_V": frame[u], "y_V": frame[y]})
        (TARGET / "cascaded_tanks").mkdir(parents=True, exist_ok=True)
        out.to_csv(TARGET / "cascaded_tanks" / name, index=False, float_format="%.9g")


def copy(source: Path) -> None:
    (TARGET / "us_macro").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source / "us_macro_statsmodels" / "macrodata.csv", TARGET / "us_macro" / "macrodata.csv")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", nargs="?", type=Path, help="folder of the full benchmark files (default: ../shared/data)",
                        default=Path(__file__).resolve().parents[3] / "shared" / "data")
    src = parser.parse_args().source
    silverbox(src)
    emps(src)
    cascaded_tanks(src)
    copy(src)
    for path in sorted(TARGET.rglob("*.*")):
        if path.suffix != ".py":
            print(f"{path.relative_to(TARGET)}: {path.stat().st_size:,} bytes")
