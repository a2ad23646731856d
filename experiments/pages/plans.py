"""The four results pages and the steps that measure them: each step is one existing experiment
command (``python <args>``), its printed output the step's section of the page.

``{results}`` in a step's arguments is the page's results folder (its records and the files the
command keeps, such as the zoo's resumable case file). A step's ``quick`` arguments are a tiny
run of the same command (the tests render each page from them); None: skipped when quick.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Step:
    name: str
    args: tuple[str, ...]
    quick: tuple[str, ...] | None = None
    text: bool = False  # plain text (a code block on the page), not Markdown


@dataclass(frozen=True)
class Page:
    title: str
    steps: tuple[Step, ...]


ZOO_SEEDS = (50000, 300)  # first seed, cases: seeds the project did not develop on (30000-30299: the page before issue 54)
ZOO = ("-m", "experiments.suites.zoo", "--seed-start", str(ZOO_SEEDS[0]))
REAL = ("silverbox", "emps", "cascaded_tanks")
DIAGNOSE = ("-m", "msam_torch", "diagnose", "--no-tensorboard")
AVS = ("-m", "experiments.bench.algebraic_vs_simulation", "--out", "{results}/algebraic_vs_simulation")
TIERS = ("-m", "experiments.suites.tiers")

PAGES = {
    "zoo": Page("The generated-systems zoo", (
        Step("zoo", (*ZOO, "--cases", str(ZOO_SEEDS[1]),
                     "--out", f"{{results}}/seeds-{ZOO_SEEDS[0]}-{sum(ZOO_SEEDS) - 1}.jsonl"),
             (*ZOO, "--cases", "1", "--no-sindy", "--out", "{results}/quick.jsonl")),
    )),
    "real-data": Page("Real data: Silverbox, EMPS, cascaded tanks", (
        *(Step(f"benchmark-{case}", ("-m", "experiments.realdata.benchmarks", case)) for case in REAL),
        Step("diagnose-emps", (*DIAGNOSE, "configs/emps.yaml", "--out", "{results}/runs/emps"),
             (*DIAGNOSE, "--no-free-run", "--no-plots", "--bootstrap", "0", "configs/emps.yaml", "--out",
              "{results}/runs/emps"), text=True),
        Step("diagnose-cascaded_tanks", (*DIAGNOSE, "configs/cascaded_tanks.yaml", "--out",
                                         "{results}/runs/cascaded_tanks"), text=True),
    )),
    "performance": Page("Performance", (
        Step("engine", ("-m", "experiments.bench.bench_engine"), text=True),
        Step("shell", ("-m", "experiments.bench.bench_shell")),
        Step("startup", ("-m", "experiments.bench.bench_startup"), text=True),
        Step("long-records", ("-m", "experiments.bench.bench_diagnose")),
        Step("algebraic-vs-simulation", AVS,
             (*AVS, "--cases", "harmonic", "--levels", "0", "--rules", "robust", "--modes", "algebraic", "--jobs", "1")),
    )),
    "suite": Page("The test suite", (
        Step("default-tier", (*TIERS, "default"), (*TIERS, "default", "--paths", "tests/test_structure.py")),
        Step("slow-tier", (*TIERS, "slow")),
    )),
}
