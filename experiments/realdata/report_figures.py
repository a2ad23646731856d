"""Render the gap report of a controlled case and of real records, and copy chosen figures into
the documentation.

    python -m experiments.realdata.report_figures   # msd_coulomb, EMPS, cascaded tanks
    python -m experiments.realdata.report_figures --configs configs/emps.yaml --images docs/images

Each report (``report.md``, ``report.html``, PNGs, ``gap_report.json``) is written to
``<out>/<config stem>``; the script prints each verdict, the figures and the seconds it took.
With ``--images``, the figures named in :data:`DOCUMENTED` are copied there as
``<config stem>_<figure>`` (the README and docs/diagnose.md show them).
"""
from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from msam_torch.diagnosis import diagnose

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ("configs/msd_coulomb.yaml", "configs/emps.yaml", "configs/cascaded_tanks.yaml")
DOCUMENTED = {"msd_coulomb": ("frequency_response_train.png", "x_ddot_residual_correlation.png")}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=[str(ROOT / c) for c in CONFIGS])
    parser.add_argument("--out", default="runs/report_figures", help="folder of the reports")
    parser.add_argument("--images", help="copy the documented figures into this folder")
    args = parser.parse_args(argv)
    for config in map(Path, args.configs):
        started = time.perf_counter()
        report = diagnose(config)
        out = Path(args.out) / config.stem
        report.save(out)
        figures = sorted(p.name for p in out.glob("*.png"))
        print(f"{config.stem}: {report.verdict} ({time.perf_counter() - started:.1f} s with the figures); "
              f"{len(figures)} figures: {', '.join(figures)}; {out / 'report.html'}")
        for name in DOCUMENTED.get(config.stem, ()) if args.images else ():
            target = Path(args.images) / f"{config.stem}_{name}"
            shutil.copyfile(out / name, target)
            print(f"  copied {name} to {target}")


if __name__ == "__main__":
    main()
