"""Start-up: ``msam --help`` and ``msam --version`` answer without loading the numerical stack;
``msam diagnose`` of a CSV record loads only what it uses (not pandas, scipy, statsmodels, pyplot or
torchdiffeq) and its process ends with its status and its printout whole; the package's
public names still import as before (they load on first use, PEP 562)."""
import subprocess
import sys

import numpy as np
import pytest
import yaml

import msam_torch
from tests.helpers import CONFIGS, simulated

HEAVY = ("torch", "pandas", "scipy")
UNUSED_BY_DIAGNOSE = ("pandas", "scipy", "statsmodels", "matplotlib.pyplot", "torchdiffeq")

RUN_AND_LIST_IMPORTS = """
import sys
from msam_torch.cli.main import main
assert main({argv!r}) == 0
loaded = [name for name in {modules!r} if name in sys.modules]
assert not loaded, loaded
"""


def run_and_check_imports(argv: list[str], modules: tuple[str, ...]) -> subprocess.CompletedProcess:
    """``main(argv)`` in a fresh process, failing if it imported any of ``modules``."""
    code = RUN_AND_LIST_IMPORTS.format(argv=argv, modules=modules)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    return done


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_do_not_import_torch_pandas_or_scipy(flag):
    done = run_and_check_imports([flag], HEAVY)
    assert ("usage: msam" in done.stdout) if flag == "--help" else done.stdout.strip() == "msam-torch 0.1.0"


def test_diagnose_of_a_csv_record_loads_only_what_it_uses(tmp_path):
    """The README's system as a CSV record (the displacement with 1 % noise, the force), its report
    written with every figure."""
    signals = simulated("msd_coulomb")
    x = signals["x"] + 0.01 * signals["x"].std() * np.random.default_rng(0).standard_normal(signals["x"].size)
    np.savetxt(tmp_path / "record.csv", np.column_stack([signals["t"], x, signals["u"]]), delimiter=",",
               header="t,x,u", comments="")
    config = yaml.safe_load((CONFIGS / "msd_coulomb.yaml").read_text())
    config["data"] = {"file": "record.csv", "time": "t", "columns": {"x": "x", "u": "u"}}
    (tmp_path / "record.yaml").write_text(yaml.safe_dump(config))
    out = tmp_path / "report"
    run_and_check_imports(["diagnose", str(tmp_path / "record.yaml"), "--out", str(out), "-q", "--bootstrap", "2"],
                          UNUSED_BY_DIAGNOSE)
    assert (out / "report.html").is_file() and len(list(out.glob("*.png"))) == 5


@pytest.mark.parametrize("argv, status", [(["--version"], 0), (["diagnose", "missing.yaml"], 2)])
def test_the_command_ends_with_its_status_and_its_printout_whole(argv, status):
    """``python -m msam_torch`` (:func:`msam_torch.__main__.command`) skips the interpreter's teardown:
    the status and both streams still come through."""
    done = subprocess.run([sys.executable, "-m", "msam_torch", *argv], capture_output=True, text=True, timeout=120,
                          check=False)
    assert done.returncode == status
    assert done.stdout.strip() == "msam-torch 0.1.0" if status == 0 else "missing.yaml" in done.stderr


def test_public_names_resolve_to_the_objects_of_their_modules():
    from msam_torch import adapt
    from msam_torch.engine.trainer import Trainer
    from msam_torch.run.adapt import adapt as api_adapt

    assert adapt is api_adapt and msam_torch.Trainer is Trainer
    for name in msam_torch.__all__:
        value = getattr(msam_torch, name)
        assert name == "__version__" or value.__name__ == name
    assert set(msam_torch.__all__) <= set(dir(msam_torch))
    with pytest.raises(AttributeError, match="no attribute 'adapted'"):
        msam_torch.adapted  # noqa: B018
