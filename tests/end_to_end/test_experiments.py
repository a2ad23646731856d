"""The reproduction experiments: an interrupted Table 4 run resumes to the same table, every script
imports, and the tests and the experiments do not import each other (the scripts run as child
processes here)."""
import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(".".join(p.relative_to(ROOT).with_suffix("").parts)
                 for p in (ROOT / "experiments").rglob("*.py") if p.name != "__init__.py")


def small_table4(tmp_path: Path) -> Path:
    config = yaml.safe_load((ROOT / "experiments" / "paper" / "table4.yaml").read_text())
    config.update(model=str(ROOT / "configs" / "harmonic.yaml"), levels=[0.0, 1.0, 2.0], trials=3, batch_trials=2,
                  overrides=["adaptation.round_robin_steps=6", "adaptation.refinement_steps=0"])
    config["variants"] = {k: config["variants"][k] for k in ("paper", "mu_one")}
    config["paper"]["success"] = config["paper"]["success"][:3]
    path = tmp_path / "table4.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def table4(config: Path, out: Path, *extra: str) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", "experiments.paper.table4", str(config), "--out", str(out), *extra],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_interrupted_table4_resumes_to_the_same_table(tmp_path):
    config = small_table4(tmp_path)
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    table4(config, whole)
    assert "stopped early" in table4(config, parts, "--max-trials", "5")  # 5 of 18 trials, then stop
    done = sorted(p.relative_to(parts) for p in (parts / "trials").rglob("*.json"))
    assert len(done) == 5  # batches of 2, 2 and 1
    before = {p: (parts / p).stat().st_mtime_ns for p in done}
    table4(config, parts)
    assert all((parts / p).stat().st_mtime_ns == t for p, t in before.items())  # finished trials not recomputed
    assert len(list((parts / "trials").rglob("*.json"))) == 18
    assert (parts / "table4.md").read_text() == (whole / "table4.md").read_text()
    assert (parts / "table4.csv").read_text() == (whole / "table4.csv").read_text()
    assert (whole / "table4.png").stat().st_size > 0 and any((whole / "tensorboard").rglob("events.*"))


def test_trials_split_into_groups_give_the_same_results_as_one_batch():
    from msam_torch.config.schema import load_config
    from msam_torch.run.trials import Trial, run_trials

    config = load_config(ROOT / "configs" / "harmonic.yaml",
                         ["adaptation.round_robin_steps=4", "adaptation.refinement_steps=2"])
    trials = [Trial(level, k) for level in (0.0, 0.5) for k in range(2)]
    whole = run_trials(config, trials, seed=3)
    groups = run_trials(config, trials, seed=3, max_elements=1)  # one trial (and candidate) per group
    for a, b in zip(whole, groups):
        assert a.equations[0].adjustments == b.equations[0].adjustments
        assert a.equations[0].exponents == pytest.approx(b.equations[0].exponents, abs=1e-9)


IMPORT_ALL = """
import importlib, json, sys
out = {}
for name in sys.argv[1:]:
    try:
        out[name] = {"doc": bool(importlib.import_module(name).__doc__)}
    except Exception as exc:
        out[name] = {"error": f"{type(exc).__name__}: {exc}"}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def imported() -> dict:
    """Every script imported as a module (``python -m`` form) in one child process: its error, or
    whether it has a docstring."""
    done = subprocess.run([sys.executable, "-c", IMPORT_ALL, *SCRIPTS], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"}, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_experiment_script_imports(script, imported):
    """Each script's imports resolve against the package as it is (a renamed module breaks the
    long benchmarks only when they run, outside the suite); `__main__` blocks do not run."""
    assert "error" not in imported[script], imported[script]["error"]
    assert imported[script]["doc"], f"{script} has no docstring saying what it measures"


def imports(folder: str, prefix: str) -> set[tuple[str, str]]:
    """(file, module) of every import of ``prefix`` or a module under it in the files under ``folder``."""
    found = set()
    for path in sorted((ROOT / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
            found |= {(path.relative_to(ROOT).as_posix(), n) for n in names if n.split(".")[0] == prefix}
    return found


def test_tests_and_experiments_do_not_import_each_other():
    assert imports("experiments", "tests") == set()
    assert imports("tests", "experiments") == set()


def interval_coverage_table(rows: list[dict], noise_free: dict, folder: Path) -> str:
    """The last line of the table ``experiments/suites/interval_coverage.py --rows`` prints."""
    path = folder / "rows.json"
    path.write_text(json.dumps({"rows": rows, "noise_free": noise_free}))
    done = subprocess.run([sys.executable, "-m", "experiments.suites.interval_coverage", "--rows", str(path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
                          check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.splitlines()[-1]


def test_interval_coverage_counts_the_intervals_that_hold_the_truth(tmp_path):
    """Three draws of Coulomb friction (truth 0): the 90 % interval holds 0 in two and the
    noise-free fit (0.03) in two, the naming interval (total +- half-width) 0 in all three; the
    spread and the mean errors are the estimates'."""
    rows = [{"case": "msd_coulomb", "noise": 0.01, "seed": k, "total": total, "half": 0.2, "interval": interval}
            for k, (total, interval) in enumerate([(0.02, [-0.01, 0.05]), (0.04, [0.01, 0.07]), (-0.03, [-0.06, 0.0])])]
    rows.append({"case": "msd_coulomb", "noise": 0.01, "seed": 3, "total": None})
    line = interval_coverage_table(rows, {"msd_coulomb": 0.03}, tmp_path)
    assert line == "| msd_coulomb | 0.01 | 3/4 | 2/3 | 2/3 | 3/3 | 0.036 | 0.030 | +0.010 | -0.020 |"
    line = interval_coverage_table(rows, {"msd_coulomb": None}, tmp_path)
    assert line.endswith("| 2/3 | - | 3/3 | 0.036 | 0.030 | +0.010 | - |")
