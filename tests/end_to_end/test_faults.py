"""Faults from outside a run (issue 18): Ctrl-C, a second run into the same folder, a closed
stdout; and the same config and seed give the same files twice."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from msam_torch.cli.main import main
from tests.helpers import CONFIGS

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
HARMONIC = str(CONFIGS / "harmonic.yaml")


def msam(*arguments, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "msam_torch", *arguments], env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


def wait_for(path: Path, process: subprocess.Popen, limit: float = 120) -> None:
    start = time.monotonic()
    while not path.exists():
        assert process.poll() is None, process.communicate()
        assert time.monotonic() - start < limit, f"{path} never appeared"
        time.sleep(0.05)


def test_a_second_run_refuses_and_ctrl_c_stops_the_first_keeping_its_best_state(tmp_path):
    out = tmp_path / "out"
    first = msam("run", HARMONIC, "-q", "--out", str(out), "adaptation.round_robin_steps=100000", cwd=tmp_path)
    try:
        wait_for(out / "tensorboard", first)  # running, past start-up, holding the folder's lock
        second = subprocess.run([sys.executable, "-m", "msam_torch", "run", HARMONIC, "--out", str(out),
                                 "adaptation.round_robin_steps=2"], env=ENV, text=True, capture_output=True,
                                timeout=120)
        assert second.returncode == 2 and second.stderr.count("\n") == 1, second.stderr
        assert "--out" in second.stderr and "another msam run" in second.stderr
        first.send_signal(signal.SIGINT)
        _, err = first.communicate(timeout=120)
    finally:
        first.kill()
    assert first.returncode == 130 and err.count("\n") == 1 and "interrupted (Ctrl-C)" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # its lock is gone, its best state written
    result = json.loads((out / "result.json").read_text())
    assert result["data"]["stopped"] == {"interrupted": True}
    assert result["equations"][0]["adapted"]["fitness"] >= result["equations"][0]["start"]["fitness"]


def test_a_closed_stdout_is_one_line_and_status_2_with_the_files_written(tmp_path):
    out = tmp_path / "out"
    done = subprocess.run(f"{sys.executable} -m msam_torch diagnose -q {HARMONIC} --out {out} | true; "
                          "exit ${PIPESTATUS[0]}", shell=True, executable="/bin/bash", env=ENV, text=True,
                          capture_output=True, timeout=300)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "broken pipe" in done.stderr, done.stderr
    report = json.loads((out / "gap_report.json").read_text())
    assert report["version"] == 1 and "Verdict" in (out / "report.md").read_text()
    assert all((out / name).stat().st_size > 1000 for name in ("free_run_train.png", "x_ddot_residual_time.png"))


def test_same_config_and_seed_give_identical_files_apart_from_timing(tmp_path, capsys):
    noisy = ["data.noise=0.01", "data.derivatives=savgol", "data.parametric_error=0.3", "data.seed=11"]
    quick = ["adaptation.round_robin_steps=3", "adaptation.refinement_steps=2"]
    for name in ("a", "b"):
        assert main(["run", HARMONIC, "--out", str(tmp_path / f"run_{name}"), "--no-tensorboard", *noisy, *quick]) == 0
        assert main(["diagnose", HARMONIC, "--out", str(tmp_path / f"diagnosis_{name}"), *noisy]) == 0
    assert (tmp_path / "run_a" / "result.json").read_bytes() == (tmp_path / "run_b" / "result.json").read_bytes()
    reports = [json.loads((tmp_path / f"diagnosis_{name}" / "gap_report.json").read_text()) for name in "ab"]
    assert all(r.pop("seconds") > 0 for r in reports)
    assert reports[0] == reports[1]
    markdown = [[line for line in (tmp_path / f"diagnosis_{name}" / "report.md").read_text().splitlines()
                 if not line.startswith("_Computed in")] for name in "ab"]
    assert markdown[0] == markdown[1] and len(markdown[0]) > 20


def test_max_seconds_stops_at_the_next_step_keeping_the_best_state(tmp_path, capsys):
    out = tmp_path / "zero"
    assert main(["run", HARMONIC, "--out", str(out), "--no-tensorboard", "--max-seconds", "0"]) == 0
    assert "stopped after --max-seconds 0" in capsys.readouterr().err
    result = json.loads((out / "result.json").read_text())
    assert result["data"]["stopped"] == {"max_seconds": 0.0}
    assert result["equations"][0]["exponents"] == [0.0, 0.0, None]  # no step taken: the starting state
    out = tmp_path / "long"  # a million round-robin steps, bounded by the limit
    assert main(["run", HARMONIC, "--out", str(out), "--no-tensorboard", "--max-seconds", "1",
                 "adaptation.round_robin_steps=1000000"]) == 0
    eq = json.loads((out / "result.json").read_text())["equations"][0]
    assert eq["adapted"]["fitness"] > eq["start"]["fitness"] and eq["exponents"] != [0.0, 0.0, None]
