"""Start-up: ``msam --help`` and ``msam --version`` answer without loading the numerical stack, and
the package's public names still import as before (they load on first use, PEP 562)."""
import subprocess
import sys

import pytest

import msam_torch

HEAVY = ("torch", "pandas", "scipy")

ANSWER_WITHOUT_HEAVY_IMPORTS = """
import runpy, sys
sys.argv = ["msam", {flag!r}]
try:
    runpy.run_module("msam_torch", run_name="__main__", alter_sys=True)
except SystemExit as stop:
    assert stop.code in (0, None), stop.code
loaded = [name for name in {heavy!r} if name in sys.modules]
assert not loaded, loaded
"""


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_do_not_import_torch_pandas_or_scipy(flag):
    code = ANSWER_WITHOUT_HEAVY_IMPORTS.format(flag=flag, heavy=HEAVY)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert ("usage: msam" in done.stdout) if flag == "--help" else done.stdout.strip() == "msam-torch 0.1.0"


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
