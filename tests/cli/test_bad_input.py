"""Every kind of bad input reaches the user as one line naming the place, exit status 2, no
traceback, and no output written (issue: measured data in)."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from msam_torch.cli.main import main
from tests.helpers import measured_case

ROOT = Path(__file__).resolve().parents[2]
QUICK = ["adaptation.round_robin_steps=2", "adaptation.refinement_steps=1"]


def displacement_only(tmp_path, frame=None, **data):
    """The oscillator measured as displacement and force only, as a CSV and a config."""
    config, full = measured_case("harmonic", every=5)
    frame = full[["t", "x", "u"]].copy() if frame is None else frame
    frame.to_csv(tmp_path / "data.csv", index=False)
    config["data"] = {"file": "data.csv", "time": "t", "columns": {"x": "x", "u": "u"}, "derivatives": "savgol", **data}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path, frame


def edit_frame(change):
    def build(tmp_path):
        _, frame = displacement_only(tmp_path)
        change(frame)
        return displacement_only(tmp_path, frame)[0]
    return build


def edit_config(change, text=False):
    def build(tmp_path):
        path, _ = displacement_only(tmp_path)
        if text:
            path.write_text(change(path.read_text()))
        else:
            config = yaml.safe_load(path.read_text())
            change(config)
            path.write_text(yaml.safe_dump(config))
        return path
    return build


def set_value(frame, column, rows, value):
    frame.loc[rows, column] = value


def irregular(frame):
    frame.loc[50:, "t"] += 0.004


def unsorted(frame):
    frame.loc[[10, 11], "t"] = frame.loc[[11, 10], "t"].to_numpy()


def duplicated(frame):
    frame.loc[21, "t"] = frame.loc[20, "t"]


def few_rows(tmp_path):
    _, frame = displacement_only(tmp_path)
    return displacement_only(tmp_path, frame.iloc[:12].copy(), window=31)[0]


CASES = {
    # name: (build config path, extra CLI arguments, fragments the message must hold)
    "missing column": (edit_config(lambda c: c["data"]["columns"].update(u="force")), [], ["data.csv", "'force'", "data.columns.u"]),
    "misspelt column": (edit_config(lambda c: c["data"]["columns"].update(x="X")), [], ["data.csv", "'X'", "did you mean 'x'"]),
    "NaN": (edit_frame(lambda f: set_value(f, "x", [7, 9], np.nan)), [], ["data.csv", "column 'x'", "lines 9, 11"]),
    "inf": (edit_frame(lambda f: set_value(f, "u", [30], np.inf)), [], ["data.csv", "column 'u'", "infinite", "line 32"]),
    "value whose differences overflow": (edit_frame(lambda f: set_value(f, "x", [40], 1e308)), [],
                                         ["data.csv", "column 'x'", "float range", "line 42"]),
    "non-monotonic time": (edit_frame(unsorted), [], ["data.csv", "not increasing", "line 13"]),
    "duplicated time": (edit_frame(duplicated), [], ["data.csv", "duplicated", "line 23"]),
    "irregular sampling": (edit_frame(irregular), [], ["data.csv", "irregular sampling", "line 52", "data.resample=true"]),
    "fewer samples than the window": (few_rows, [], ["data.csv", "column 'x'", "12 samples", "window of 31"]),
    "constant signal to differentiate": (edit_frame(lambda f: set_value(f, "x", slice(None), 0.25)), [], ["data.csv", "column 'x'", "constant"]),
    "unknown config key": (edit_config(lambda c: c["data"].update(windw=31)), [], ["data.windw"]),
    "wrong type": (edit_config(lambda c: c["data"].update(window="wide")), [], ["data.window"]),
    "malformed YAML": (edit_config(lambda t: t.replace("data:", "data: [", 1), text=True), [],
                       ["config.yaml", "malformed YAML at line"]),
    "expression outside the whitelist": (edit_config(lambda c: c["model"]["equations"][0]["adjustments"].__setitem__(
        0, "abs(x).__class__")), [], ["model.equations[0].adjustments[0]"]),
    "empty validation range": (edit_config(lambda c: c["data"].update(validation={"start": 50.0, "stop": 60.0})), [],
                               ["data.validation", "selects no samples", "data.csv"]),
    "empty training range by index": (edit_config(lambda c: c["data"].update(train={"start": 500, "by": "index"})), [],
                                      ["data.train", "selects no samples"]),
    "unknown estimator override": (edit_config(lambda c: None), ["data.derivatives=wavelet"], ["data.derivatives"]),
}


@pytest.mark.parametrize("case", CASES)
def test_bad_input_names_the_place_exits_2_and_writes_nothing(tmp_path, capsys, case):
    build, extra, fragments = CASES[case]
    config = build(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(config), "--out", str(out), *QUICK, *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err and err.count("\n") == 1, err
    for fragment in fragments:
        assert fragment in err, (fragment, err)
    assert not out.exists()


def test_resampling_is_opt_in_and_recorded(tmp_path, capsys):
    config = edit_frame(irregular)(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(config), "--out", str(out), "--no-tensorboard", *QUICK, "data.resample=true"]) == 0
    import json

    data = json.loads((out / "result.json").read_text())["data"]
    assert data["resampled"] == {"from": 200, "to": 200, "method": "linear"}
    assert data["sample_time"] == pytest.approx(3.0 / 999 * 5)
    assert data["derivatives"]["x"]["method"] == "savgol" and data["derivatives"]["x"]["window"] >= 5


@pytest.mark.slow
def test_a_subprocess_run_fails_cleanly_without_writing(tmp_path):
    config = edit_frame(lambda f: set_value(f, "x", [3], np.nan))(tmp_path)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "msam_torch", "run", str(config), "--out", str(out)],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and "column 'x'" in done.stderr and "line 5" in done.stderr
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "data.csv"]
