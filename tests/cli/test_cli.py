import json

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from msam_torch.cli.main import main
from tests.helpers import CONFIGS, QUICK


def test_run_prints_the_adapted_equation_and_writes_result_json(tmp_path, capsys):
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path), "--no-tensorboard"]) == 0
    printed = capsys.readouterr().out
    assert "adapted:  x_ddot = -26.13 x_dot|x_dot|^1.000 - 346.7 x|x|^2.000 + 0.002667 u" in printed
    result = json.loads((tmp_path / "result.json").read_text())
    eq = result["equations"][0]
    assert result["version"] == 1 and result["config"]["adaptation"]["round_robin_steps"] == 15
    assert [r["adjustments"] for r in eq["ranking"]][0] == ["abs(x_dot)", "abs(x)"]
    assert len(eq["ranking"]) == 4 and all({"fitness", "exponents", "diverged"} <= set(r) for r in eq["ranking"])
    assert eq["ranking"][0]["fitness"] >= max(r["fitness"] for r in eq["ranking"])
    assert set(eq["start"]) == set(eq["adapted"]) == {"fitness", "sum_abs_error", "rho"}
    assert not (tmp_path / "tensorboard").exists()


def test_tensorboard_holds_every_listed_scalar_and_the_resolved_config(tmp_path):
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path), "--quiet", *QUICK]) == 0
    log_dir = tmp_path / "tensorboard"
    assert "round_robin_steps: 3" in (log_dir / "config.yaml").read_text()
    events = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    events.Reload()
    tags = set(events.Tags()["scalars"])
    for measure in ("fitness", "sum_abs_error", "rho", "mu", "cond_scaled", "cond_unscaled", "gamma_0", "gamma_1"):
        for candidate in ("abs_x_dot-abs_x_dot", "abs_x_dot-abs_x", "abs_x-abs_x_dot", "abs_x-abs_x"):
            tag = f"x_ddot/round_robin/{measure}/{candidate}"
            assert tag in tags, tag
            assert [e.step for e in events.Scalars(tag)] == [1, 2, 3]
        assert len(events.Scalars(f"x_ddot/refinement/{measure}/winner")) == 2


def test_same_seed_gives_an_identical_result_json(tmp_path):
    noisy = ["data.noise=0.01", "data.derivatives=savgol", "data.parametric_error=0.5", "data.seed=7", *QUICK]
    for name in ("a", "b"):
        assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path / name), "--no-tensorboard", *noisy]) == 0
    assert (tmp_path / "a" / "result.json").read_bytes() == (tmp_path / "b" / "result.json").read_bytes()
    other = ["data.seed=8" if a == "data.seed=7" else a for a in noisy]
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path / "c"), "--no-tensorboard", *other]) == 0
    assert (tmp_path / "a" / "result.json").read_bytes() != (tmp_path / "c" / "result.json").read_bytes()


@pytest.mark.parametrize("override, key", [
    ("adaptation.step_sise=one", "adaptation.step_sise"),
    ("adaptation.round_robin_steps=many", "adaptation.round_robin_steps"),
    ("adaptation.step_size=huge", "adaptation.step_size"),
    ("model.equations[0]=1", "model.equations[0]"),
])
def test_bad_config_values_name_the_key_and_write_nothing(tmp_path, capsys, override, key):
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--out", str(tmp_path / "out"), override]) == 2
    assert key in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_expression_outside_the_whitelist_is_rejected_with_its_key(tmp_path, capsys):
    text = (CONFIGS / "harmonic.yaml").read_text().replace("theta: -k/m", "theta: \"__import__('os').getcwd()\"")
    config = tmp_path / "bad.yaml"
    config.write_text(text)
    assert main(["run", str(config), "--out", str(tmp_path / "out")]) == 2
    assert "model.equations[0].components[1].theta" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_closed_stdout_is_one_line_and_status_2_with_the_files_complete(tmp_path):
    """`msam run ... | head` closing the pipe first: no traceback, one line naming the broken pipe,
    the files kept (the same for diagnose: tests/end_to_end/test_faults.py)."""
    import subprocess
    import sys

    out = tmp_path / "out"
    process = subprocess.Popen([sys.executable, "-m", "msam_torch", "run", str(CONFIGS / "harmonic.yaml"),
                                "--out", str(out), "--quiet", *QUICK], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # the reader is gone before anything is printed
    stderr = process.stderr.read()
    assert process.wait() == 2
    assert stderr.strip().splitlines() == [
        "error: standard output was closed before the printout ended (broken pipe); the files are written"]
    assert json.loads((out / "result.json").read_text())["equations"]
