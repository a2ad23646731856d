"""Progress through the logging module: `msam diagnose` writes progress lines to a redirected
stderr while it runs; the handler's lines (ETA, heartbeat) and bar (total); -q silences them."""
import io
import logging
import subprocess
import sys
import time

from msam_torch.cli.main import main
from msam_torch.run.progress import ProgressHandler, logging_to, step
from tests.helpers import CONFIGS, QUICK

ROOT = CONFIGS.parent



def test_diagnose_writes_progress_to_a_log_before_it_finishes(tmp_path):
    process = subprocess.Popen([sys.executable, "-m", "msam_torch", "diagnose", str(CONFIGS / "emps.yaml"),
                                "--out", str(tmp_path / "out")], cwd=ROOT, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
    first = process.stderr.readline()
    while first.startswith("warning: "):  # emps.yaml's two copies of the viscous term, warned about first
        first = process.stderr.readline()
    running = process.poll() is None  # the line came while the diagnosis was still running
    rest = process.stderr.read()
    assert process.wait() == 0
    assert running and first.startswith("diagnose: 0/3 reading the data")
    lines = [first.strip()] + rest.splitlines()
    stages = [line.split(" (")[0] for line in lines]
    stages = [s for k, s in enumerate(stages) if k == 0 or s != stages[k - 1]]  # a stage's heartbeats once
    assert stages[:3] == [
        "diagnose: 0/3 reading the data", "diagnose: 1/3 equation q_ddot", "diagnose: 2/3 comparing the models"]
    assert "about" in lines[1] and lines[-1].startswith("info: writing the report to ")


def test_run_logs_steps_with_total_and_quiet_silences_them(tmp_path, capsys):
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path / "a"), "--no-tensorboard", *QUICK]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("x_ddot: 1/5 round robin") and err[-1].startswith("x_ddot: 5/5 refinement")
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path / "b"), "-q", "--no-tensorboard",
                 *QUICK]) == 0
    assert capsys.readouterr().err == ""
    assert logging.getLogger("msam_torch").handlers == []


def test_heartbeat_lines_while_a_stage_runs_and_a_bar_on_a_terminal():
    stream = io.StringIO()
    with logging_to(stream, every=0.05) as handler:
        assert not handler.terminal
        step(logging.getLogger("msam_torch.test"), "work", "a long stage", 1, 4)
        time.sleep(0.5)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("work: 1/4 a long stage") and "left" in lines[0]
    assert len(lines) >= 3 and all(line.startswith("work: 1/4 a long stage") for line in lines)
    terminal = io.StringIO()
    handler = ProgressHandler(terminal, terminal=True)
    logger = logging.getLogger("msam_torch.bar")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        for done in range(3):
            step(logger, "work", f"stage {done}", done, 3)
        assert (handler.bar.n, handler.bar.total, handler.bar.desc, handler.bar.postfix) == (2, 3, "work", "stage 2")
    finally:
        logger.removeHandler(handler)
        handler.close()
    assert "0/3" in terminal.getvalue()
