"""The round robin sharded over two gloo processes under torchrun gives the single-process result."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "sode3.yaml"
OVERRIDES = ["adaptation.round_robin_steps=8", "adaptation.refinement_steps=4"]


def run(command, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]


@pytest.mark.skipif(shutil.which("torchrun") is None and not (Path(sys.executable).parent / "torchrun").exists(),
                    reason="torchrun not installed")
def test_torchrun_two_ranks_match_one_process(tmp_path):
    torchrun = str(Path(sys.executable).parent / "torchrun") if (Path(sys.executable).parent / "torchrun").exists() else "torchrun"
    single, sharded = tmp_path / "single.json", tmp_path / "sharded.json"
    run([sys.executable, "-m", "msam_torch.run.distributed", str(CONFIG), *OVERRIDES, "--out", str(single)], tmp_path)
    run([torchrun, "--nproc_per_node=2", "--master_port=29517", "-m", "msam_torch.run.distributed", str(CONFIG), *OVERRIDES,
         "--out", str(sharded)], tmp_path)
    one, two = json.loads(single.read_text()), json.loads(sharded.read_text())
    assert len(one["equations"]) == len(two["equations"]) == 3
    for a, b in zip(one["equations"], two["equations"]):
        assert a["adjustments"] == b["adjustments"]
        assert [r["candidate"] for r in a["ranking"]] == [r["candidate"] for r in b["ranking"]]
        for x, y in zip(a["exponents"], b["exponents"]):
            assert abs(x - y) <= 1e-9
        for ra, rb in zip(a["ranking"], b["ranking"]):
            assert ra["diverged"] == rb["diverged"]
            assert all(abs(x - y) <= 1e-9 for x, y in zip(ra["exponents"], rb["exponents"]))
