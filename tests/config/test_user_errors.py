"""The corpus of user errors (issue 18): every input a careless user or an attacker can give ends
in one line naming the place and exit status 2 (3 for a run or diagnosis that learnt nothing, its
result or report written), never a traceback, and leaves nothing half-written behind.

Each case builds its inputs in a fresh folder and runs ``msam`` in-process and asserts its exit
status; ``pytest -s -k outcome_table`` prints the table of cases by class and exit status.
"""
from __future__ import annotations

import collections
import gzip
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from msam_torch.cli.main import main
from msam_torch.run.outputs import locked
from tests.helpers import CONFIGS, measured_case

QUICK = ["adaptation.round_robin_steps=2", "adaptation.refinement_steps=1"]
THETA = "model.equations[0].components[0].theta"


def measured(tmp_path: Path, change=None, rows: int | None = None, folder: str = ".", edit=None, **data) -> Path:
    """The harmonic oscillator measured in full (exact derivatives) as data.csv beside config.yaml;
    ``change(frame)`` edits the table, ``edit(config)`` the config."""
    config, frame = measured_case("harmonic", every=5)
    frame = frame.iloc[:rows].copy() if rows else frame
    if change is not None:
        change(frame)
    frame.to_csv(tmp_path / "data.csv", index=False)
    config["data"] = {"file": "data.csv", "time": "t", "columns": {c: c for c in ("x", "x_dot", "x_ddot", "u")},
                      "derivatives": "exact", **data}
    if edit is not None:
        edit(config)
    (tmp_path / folder).mkdir(exist_ok=True)
    path = tmp_path / folder / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def bundled(tmp_path: Path, edit=None, text=None) -> Path:
    """configs/harmonic.yaml (simulated data) copied, edited as a dict or replaced by ``text``."""
    raw = yaml.safe_load((CONFIGS / "harmonic.yaml").read_text())
    if edit is not None:
        edit(raw)
    path = tmp_path / "config.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(raw))
    return path


def component(**values):
    def edit(raw):
        raw["model"]["equations"][0]["components"][0].update(values)
    return edit


def theta(value):
    return lambda tmp_path: bundled(tmp_path, component(theta=value))


def override(*items):
    return lambda tmp_path: (bundled(tmp_path), list(items))


def text(content: str | bytes, name="config.yaml"):
    def build(tmp_path):
        path = tmp_path / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        return path
    return build


def data_file(content: bytes, name="data.csv"):
    def build(tmp_path):
        path = measured(tmp_path)
        (tmp_path / "data.csv").unlink()
        target = tmp_path / name
        if content is None:
            target.mkdir()
        else:
            target.write_bytes(content)
        config = yaml.safe_load(path.read_text())
        config["data"]["file"] = name
        path.write_text(yaml.safe_dump(config))
        return path
    return build


def frame(change=None, **kwargs):
    return lambda tmp_path: measured(tmp_path, change, **kwargs)


def column_set(name, value):
    def change(f):
        f[name] = value(f) if callable(value) else value
    return change


def scaled(factor):
    def change(f):
        for c in ("x", "x_dot", "x_ddot", "u"):
            f[c] = f[c] * factor
    return change


def rows_set(name, rows, value):
    def change(f):
        f.loc[rows, name] = value
    return change


def nested(levels: int) -> str:
    return "[" * levels + "]" * levels


def secret_outside(tmp_path):
    (tmp_path / "secret.csv").write_text("SECRET-TOKEN-42,other\n1,2\n3,4\n")
    return measured(tmp_path, folder="project", edit=lambda c: c["data"].update(file="../secret.csv"))


def diverging(start):
    def build(tmp_path):
        def edit(raw):
            for c in raw["model"]["equations"][0]["components"][:2]:
                c["start"] = start
        return bundled(tmp_path, edit)
    return build


def parabola(tmp_path: Path) -> Path:
    """x = t^2/2 exactly, only x and u measured: its acceleration, estimated from x, is 1 to the
    estimate's precision."""
    def change(f):
        f["x"] = f["t"] ** 2 / 2

    def edit(config):
        config["data"].update(columns={"x": "x", "u": "u"}, derivatives="auto")
    return measured(tmp_path, change, edit=edit)


def tanks(change=None, rows: int = 120, edit=None):
    """The cascaded tanks (evaluated by simulation) on the first ``rows`` samples of their record;
    ``change(record)`` edits the table, ``edit(config)`` the config."""
    def build(tmp_path):
        import pandas as pd

        record = pd.read_csv(CONFIGS.parent / "msam_torch" / "data" / "datasets" / "cascaded_tanks" / "estimation.csv",
                             comment="#").iloc[:rows]
        if change is not None:
            change(record)
        record.to_csv(tmp_path / "tanks.csv", index=False)
        raw = yaml.safe_load((CONFIGS / "cascaded_tanks.yaml").read_text())
        raw["data"].update(file="tanks.csv")
        raw["data"].pop("validation_file")
        raw["adaptation"]["simulation"]["prefit_steps"] = 1
        if edit is not None:
            edit(raw)
        (tmp_path / "config.yaml").write_text(yaml.safe_dump(raw))
        return tmp_path / "config.yaml"
    return build


def tank_starts(start):
    def edit(raw):
        for equation in raw["model"]["equations"]:
            for c in equation["components"]:
                c["start"] = start
    return edit


def guess(value):
    def edit(raw):
        raw["adaptation"]["simulation"]["initial_guess"] = {"x1": value}
    return edit


def tank_input_adjustment(raw):
    raw["model"]["equations"][0]["adjustments"].append("abs(u)")


ROOT_CANNOT_BE_REFUSED = pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
CUDA = torch.cuda.is_available()

# class: {case: (build(tmp_path) -> config path or (path, extra args), extra CLI args, exit status, fragments)}
CORPUS: dict[str, dict[str, tuple]] = {
    "expression evaluation": {
        "division by zero": (theta("1/0"), [], 2, [THETA, "'1/0'", "division by zero"]),
        "zero parameter under -c/m": (override("model.parameters.m=0"), [], 2, [THETA, "'-c/m'", "m = 0", "division by zero"]),
        "zero to a negative power": (theta("0**-1"), [], 2, [THETA, "'0**-1'"]),
        "overflow 10**400": (theta("10**400"), [], 2, [THETA, "'10**400'", "overflow"]),
        "overflow by ^": (theta("10^400"), [], 2, [THETA, "overflow"]),
        "complex (-1)**0.5": (theta("(-1)**0.5"), [], 2, [THETA, "complex"]),
        "complex inside a function": (theta("sqrt((-8)**(1/3))"), [], 2, [THETA, "complex"]),
        "log(0)": (theta("log(0)"), [], 2, [THETA, "'log(0)'", "-inf"]),
        "sqrt(-1)": (theta("sqrt(-1)"), [], 2, [THETA, "'sqrt(-1)'", "nan"]),
        "exp overflow": (theta("exp(1000)"), [], 2, [THETA, "inf"]),
        "inf minus inf": (theta("exp(1000)-exp(1000)"), [], 2, [THETA, "not a finite number"]),
        "400-digit literal": (theta("9" * 400), [], 2, [THETA, "beyond float64"]),
        "400-digit YAML integer": (lambda p: bundled(p, text=(CONFIGS / "harmonic.yaml").read_text().replace(
            "theta: -c/m", "theta: " + "7" * 400)), [], 2, [THETA, "float64"]),
        "1e999 literal": (theta("1e999*c"), [], 2, [THETA, "beyond float64"]),
        "nesting deeper than the bound": (theta("-(" * 120 + "c" + ")" * 120), [], 2, [THETA, "nested deeper"]),
        "longer than 500 characters": (theta("+".join(["c"] * 300)), [], 2, [THETA, "longer than 500"]),
        "parameter huge after perturbation": (override("data.parametric_error=1e308"), [], 2, [THETA, "not a finite"]),
    },
    "expression syntax": {
        "dunder attribute": (theta("m.__class__"), [], 2, [THETA, "Attribute"]),
        "import call": (theta("__import__('os')"), [], 2, [THETA, "function not allowed"]),
        "lambda": (theta("lambda: 1"), [], 2, [THETA, "Lambda"]),
        "string constant": (theta("'a' * 3"), [], 2, [THETA, "only numbers"]),
        "comparison": (theta("c < m"), [], 2, [THETA, "Compare"]),
        "conditional": (theta("c if m else 1"), [], 2, [THETA, "IfExp"]),
        "boolean operator": (theta("c and m"), [], 2, [THETA, "BoolOp"]),
        "list literal": (theta("[c, m]"), [], 2, [THETA, "List"]),
        "unknown name": (theta("q/m"), [], 2, [THETA, "unknown name 'q'", "config.yaml)"]),
        "unknown function": (theta("floor(c)"), [], 2, [THETA, "function not allowed"]),
        "two arguments": (theta("sqrt(c, m)"), [], 2, [THETA, "exactly one argument"]),
        "keyword argument": (theta("sqrt(x=c)"), [], 2, [THETA, "exactly one argument"]),
        "syntax error": (theta("c/(m"), [], 2, [THETA, "cannot parse"]),
        "empty": (theta(""), [], 2, [THETA, "empty expression"]),
        "boolean value": (theta(True), [], 2, [THETA]),
        "null value": (theta(None), [], 2, [THETA]),
        "list value": (theta([1, 2]), [], 2, [THETA]),
        "null byte": (theta("c\x00"), [], 2, [THETA]),
        "walrus": (theta("(y := 3)"), [], 2, [THETA, "NamedExpr"]),
        "adjustment unknown name": (lambda p: bundled(p, lambda r: r["model"]["equations"][0]["adjustments"].__setitem__(
            0, "abs(y)")), [], 2, ["model.equations[0].adjustments[0]", "unknown name 'y'"]),
        "target an input's derivative": (lambda p: bundled(p, lambda r: r["model"]["equations"][0].__setitem__(
            "target", "u_dot")), [], 2, ["model.equations[0].target", "'u_dot' is not the derivative of a state"]),
        "target above the states": (lambda p: bundled(p, lambda r: r["model"]["equations"][0].__setitem__(
            "target", "x_dddot")), [], 2, ["model.equations[0].target"]),
        "term divides by zero on the data": (lambda p: bundled(p, component(term="x_dot/0")), [], 2,
                                             ["components[0].term", "not finite"]),
        "adjustment log of a signal through zero": (lambda p: bundled(p, lambda r: r["model"]["equations"][0][
            "adjustments"].__setitem__(1, "abs(log(abs(x)))")), [], 2, ["adjustments[1]", "not finite"]),
    },
    "YAML": {
        "malformed": (text("model: [\n"), [], 2, ["config.yaml", "malformed YAML at line"]),
        "10,000-level flow sequence": (text("model: " + nested(10_000) + "\n"), [], 2, ["line 1", "nested deeper than 64"]),
        "10,000-level flow mapping": (text("model: " + "{a: " * 10_000 + "1" + "}" * 10_000 + "\n"), [], 2, ["nested deeper"]),
        "duplicated top-level key": (lambda p: bundled(p, text=(CONFIGS / "harmonic.yaml").read_text() + "data: {seed: 3}\n"),
                                     [], 2, ["config.yaml", "duplicated key 'data'", "line"]),
        "duplicated parameter": (lambda p: bundled(p, text=(CONFIGS / "harmonic.yaml").read_text().replace(
            "{m: 375.0,", "{m: 375.0, m: 1.0,")), [], 2, ["duplicated key 'm'"]),
        "top level a list": (text("- 1\n- 2\n"), [], 2, ["top level must be a mapping"]),
        "empty file": (text(""), [], 2, ["top level must be a mapping"]),
        "not UTF-8": (text(b"\xff\xfe\x00model"), [], 2, ["config.yaml", "cannot read"]),
        "python object tag": (text("model: !!python/object/apply:os.system ['true']\n"), [], 2, ["malformed YAML"]),
        "alias bomb": (text("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
                            "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
                            "model: {states: [*d, *d, *d, *d, *d, *d, *d, *d, *d]}\n"), [], 2, ["model"]),
        "missing config": (lambda p: p / "nothing.yaml", [], 2, ["nothing.yaml", "no such config"]),
        "config is a folder": (lambda p: p, [], 2, ["cannot read"]),
        "unknown top-level key": (override("modle.states=[x]"), [], 2, ["modle"]),
        "unknown data key": (override("data.windw=31"), [], 2, ["data.windw", "did you mean 'window'?"]),
        "misspelt optional key": (override("data.colums.x=x"), [], 2, ["data.colums", "did you mean 'columns'?"]),
        "unknown adaptation key": (override("adaptation.stepsize=one"), [], 2,
                                   ["adaptation.stepsize", "did you mean 'step_size'?"]),
        "unknown simulation key": (override("adaptation.simulation.solver=rk4"), [], 2, ["adaptation.simulation.solver"]),
        "unknown range key": (override("data.train.begin=0"), [], 2, ["data.train.begin"]),
        "unknown component key": (lambda p: bundled(p, component(thetta=1)), [], 2,
                                  ["model.equations[0].components[0].thetta"]),
        "misspelt required key": (lambda p: bundled(p, lambda r: r["model"]["equations"][0].__setitem__(
            "adjustmens", r["model"]["equations"][0].pop("adjustments"))), [], 2,
            ["model.equations[0].adjustments", "'adjustmens' is given: a misspelling of 'adjustments'?"]),
        "unknown initial_guess state": (override("adaptation.simulation.initial_guess.zz=1"), [], 2,
                                        ["adaptation.simulation.initial_guess.zz", "not a state"]),
    },
    "config values": {
        "seed -1": (override("data.seed=-1"), [], 2, ["data.seed"]),
        "seed 2**70": (override(f"data.seed={2**70}"), [], 2, ["data.seed", "less than"]),
        "seed 2**64": (override(f"data.seed={2**64}"), [], 2, ["data.seed"]),
        "seed fraction": (override("data.seed=1.5"), [], 2, ["data.seed"]),
        "device foo": (override("adaptation.device=foo"), [], 2, ["adaptation.device", "'foo'"]),
        "device cuda:99": (override("adaptation.device=cuda:99"), [], 2, ["adaptation.device", "cuda:99"]),
        "device empty": (override("adaptation.device="), [], 2, ["adaptation.device"]),
        "damping inf": (override("adaptation.damping=.inf"), [], 2, ["adaptation.damping", "finite"]),
        "damping nan": (override("adaptation.damping=.nan"), [], 2, ["adaptation.damping"]),
        "damping negative": (override("adaptation.damping=-1"), [], 2, ["adaptation.damping"]),
        "gamma_limit zero": (override("adaptation.gamma_limit=0"), [], 2, ["adaptation.gamma_limit"]),
        "dgamma zero": (override("adaptation.dgamma=0"), [], 2, ["adaptation.dgamma"]),
        "round_robin_steps zero": (override("adaptation.round_robin_steps=0"), [], 2, ["adaptation.round_robin_steps"]),
        "round_robin_steps 1e8 as text": (override("adaptation.round_robin_steps=1e8"), [], 2, ["adaptation.round_robin_steps"]),
        "refinement_steps negative": (override("adaptation.refinement_steps=-1"), [], 2, ["adaptation.refinement_steps"]),
        "chunk_size zero": (override("adaptation.chunk_size=0"), [], 2, ["adaptation.chunk_size"]),
        "dtype float16": (override("adaptation.dtype=float16"), [], 2, ["adaptation.dtype"]),
        "step_size unknown": (override("adaptation.step_size=huge"), [], 2, ["adaptation.step_size"]),
        "evaluation unknown": (override("adaptation.evaluation=guess"), [], 2, ["adaptation.evaluation"]),
        "solver unknown": (override("adaptation.simulation.method=dopri5"), [], 2, ["adaptation.simulation.method"]),
        "substeps zero": (override("adaptation.simulation.substeps=0"), [], 2, ["adaptation.simulation.substeps"]),
        "noise negative": (override("data.noise=-0.1"), [], 2, ["data.noise"]),
        "noise inf": (override("data.noise=.inf"), [], 2, ["data.noise"]),
        "parametric_error negative": (override("data.parametric_error=-1"), [], 2, ["data.parametric_error"]),
        "window 2": (override("data.window=2"), [], 2, ["data.window"]),
        "cutoff zero": (override("data.cutoff=0"), [], 2, ["data.cutoff"]),
        "sample_time zero": (override("data.sample_time=0"), [], 2, ["data.sample_time"]),
        "estimator unknown": (override("data.derivatives=wavelet"), [], 2, ["data.derivatives"]),
        "parameter inf": (override("model.parameters.m=.inf"), [], 2, ["model.parameters.m"]),
        "parameter 1e400 as text": (override("model.parameters.m=1e400"), [], 2, ["model.parameters.m"]),
        "parameter 400 digits": (override("model.parameters.m=" + "9" * 400), [], 2, ["model.parameters.m", "float64"]),
        "start exponent 400 digits": (lambda p: bundled(p, component(start=int("9" * 400))), [], 2,
                                      ["model.equations[0].components[0].start"]),
        "no states": (override("model.states=[]"), [], 2, ["model.states"]),
        "system and file": (override("data.file=data.csv"), [], 2, ["data", "exactly one"]),
        "unknown system": (override("data.system=pendulum"), [], 2, ["pendulum"]),
    },
    "override syntax": {
        "no key": (override("=1"), [], 2, ["key.path=value"]),
        "scalar through a section": (override("adaptation.damping.x=1"), [], 2, ["adaptation.damping"]),
        "section replaced by a number": (override("adaptation=3"), [], 2, ["adaptation"]),
        "malformed value": (override("data.seed=[1"), [], 2, ["data.seed", "malformed value"]),
        "deeply nested value": (override("data.seed=" + nested(5_000)), [], 2, ["data.seed", "nested deeper"]),
        "duplicated key in a value": (override("data.train={start: 1, start: 2}"), [], 2, ["data.train", "duplicated key"]),
        "index syntax": (override("model.equations[0]=1"), [], 2, ["model.equations[0]"]),
        "bad value named as the override": (override("data.window=2"), [], 2,
                                            ["data.window", "(command-line override 'data.window=2')"]),
    },
    "command line": {
        "threads -1": (bundled, ["--threads", "-1"], 2, ["--threads", "'-1'"], "diagnose"),
        "threads 0": (bundled, ["--threads", "0"], 2, ["--threads"], "diagnose"),
        "threads text": (bundled, ["--threads", "many"], 2, ["--threads", "'many'"], "diagnose"),
        "bootstrap -3": (bundled, ["--bootstrap", "-3"], 2, ["--bootstrap", "'-3'"], "diagnose"),
        "solver unknown": (bundled, ["--solver", "rk5"], 2, ["argument --solver", "'rk5'", "torchdiffeq"], "diagnose"),
        "unknown option": (bundled, ["--fast"], 2, ["unrecognized arguments: --fast"]),
        "out is a file (run)": (bundled, ["--out", "{tmp}/config.yaml"], 2, ["--out", "existing file"]),
        "out is a file (diagnose)": (bundled, ["--out", "{tmp}/config.yaml"], 2, ["--out", "existing file"], "diagnose"),
        "out below a file": (bundled, ["--out", "{tmp}/config.yaml/out"], 2, ["--out", "is a file"]),
        "out in /proc": (bundled, ["--out", "/proc/msam-out"], 2, ["--out", "not writable"]),
        "out holds other files (diagnose)": (lambda p: (bundled(p), ["--out", str(p)]), [], 2,
                                             ["--out", "holds other files", "config.yaml"], "diagnose"),
        "diagnose into the current folder": (bundled, ["--out", "."], 2, ["--out", "holds the current folder"],
                                             "diagnose"),
        "diagnose data missing": (bundled, ["--data", "{tmp}/none.csv"], 2, ["none.csv", "no such data file"], "diagnose"),
        "diagnose validate missing": (frame(), ["--validate", "{tmp}/none.csv"], 2, ["none.csv"], "diagnose"),
        "diagnose validate beside a simulated record": (bundled, ["--validate", "{tmp}/none.csv"], 2,
                                                        ["validation", "measured training data"], "diagnose"),
    },
    "data": {
        "missing file": (data_file(b"t,x\n1,2\n", name="other.csv"), [], 2, ["other.csv"]),
        "empty file": (data_file(b""), [], 2, ["data.csv", "cannot read as CSV"]),
        "header only": (data_file(b"t,x,x_dot,x_ddot,u\n"), [], 2, ["data.csv"]),
        "binary garbage": (data_file(bytes(range(256)) * 8), [], 2, ["data.csv"]),
        "corrupt gzip": (data_file(b"\x1f\x8b\x08\x00garbage", name="data.csv.gz"), [], 2, ["data.csv.gz"]),
        "gzip of text that is not a table": (data_file(gzip.compress(b"\x00\x01\x02"), name="data.csv.gz"), [], 2,
                                             ["data.csv.gz"]),
        "corrupt parquet": (data_file(b"PAR1garbagePAR1", name="data.parquet"), [], 2, ["data.parquet", "Parquet"]),
        "data file is a folder": (data_file(None), [], 2, ["data.csv"]),
        "NaN": (frame(rows_set("x", [7, 9], np.nan)), [], 2, ["column 'x'", "lines 9, 11"]),
        "inf": (frame(rows_set("u", [30], np.inf)), [], 2, ["column 'u'", "infinite"]),
        "text in a number column": (frame(lambda f: f.__setitem__("x_dot", f["x_dot"].astype(object).where(
            f.index != 4, "abc"))), [], 2, ["column 'x_dot'", "non-numeric"]),
        "duplicated time": (frame(rows_set("t", [21], 0.0)), [], 2, ["data.csv"]),
        "irregular time": (frame(column_set("t", lambda f: f["t"] + (f.index >= 50) * 0.004), derivatives="savgol"), [], 2,
                           ["irregular sampling"]),
        "five samples": (frame(rows=5), [], 2, ["5 samples", "model.equations[0]", "at least 7"]),
        "six samples": (frame(rows=6), [], 2, ["6 samples", "at least 7"]),
        "constant target": (frame(column_set("x_ddot", 1.0)), [], 3, ["'x_ddot'", "constant"]),
        "target constant to rounding": (frame(column_set("x_ddot", lambda f: 1.0 + np.arange(len(f)) * 1e-17)), [], 3,
                                        ["'x_ddot'", "constant up to rounding"]),
        "zero target": (frame(column_set("x_ddot", 0.0)), [], 3, ["'x_ddot'", "constant"]),
        "adjustment varying by one ulp": (frame(column_set("x", lambda f: np.where(np.arange(len(f)) % 2, 0.5,
                                                                                   np.nextafter(0.5, 1)))), [], 2,
                                          ["abs(x)", "constant magnitude"]),
        "data scaled by 1e-300": (frame(scaled(1e-300)), [], 2, ["rescale the data", "float64"]),
        "data scaled by 1e-160": (frame(scaled(1e-160)), [], 2, ["rescale the data"]),
        "data scaled by 1e200": (frame(scaled(1e200)), [], 2, ["rescale the data"]),
        "missing column names the columns": (frame(edit=lambda c: c["data"]["columns"].update(u="force")), [], 2,
                                             ["'force'", "data.columns.u", "columns are"]),
        "missing time column": (frame(time="time"), [], 2, ["'time'", "data.time"]),
        "no data section beside --data": (lambda p: measured(p, edit=lambda c: c.pop("data")),
                                          ["--data", "{tmp}/data.csv"], 2, ["data.time", "config.yaml"], "diagnose"),
        "column for an unknown signal": (frame(edit=lambda c: c["data"]["columns"].update(zz="x")), [], 2, ["zz"]),
        "empty training range": (frame(train={"start": 100.0}), [], 2, ["data.train", "selects no samples"]),
        "empty validation range": (frame(validation={"start": 50.0, "stop": 60.0}), [], 2, ["data.validation"]),
        "missing validation file": (frame(validation_file="held.csv"), [], 2, ["held.csv", "no such data file",
                                                                          "data.validation_file"]),
        "neither system nor file": (lambda p: bundled(p, lambda r: r["data"].pop("system")), [], 2, ["data", "exactly one"]),
    },
    "records simulated against": {  # the measured outputs take the targets' part (adaptation.evaluation: simulation)
        "record times 1e200": (tanks(column_set("y_V", lambda f: f["y_V"] * 1e200)), [], 2,
                               ["tanks.csv", "'x2'", "rescale the data"]),
        "constant output": (tanks(column_set("y_V", 3.0)), [], 3, ["measured output 'x2'", "constant up to rounding"]),
        "output constant to rounding": (tanks(column_set("y_V", lambda f: 3.0 + np.arange(len(f)) * 1e-16)), [], 3,
                                        ["measured output 'x2'", "constant up to rounding"]),
        "five samples": (tanks(rows=5), [], 2, ["5 samples", "model.equations[0, 1]", "at least"]),
        "input adjustment of constant magnitude": (tanks(column_set("u_V", 4.0), edit=tank_input_adjustment), [], 2,
                                                   ["'abs(u)'", "model.equations[0].adjustments[1]", "constant magnitude"]),
        "constant output, diagnose": (tanks(column_set("y_V", 3.0)), [], 3, ["measured output 'x2'"], "diagnose"),
    },
    "diagnose": {
        "five samples": (frame(rows=5), [], 2, ["5 samples", "at least 7"], "diagnose"),
        "data scaled by 1e-300": (frame(scaled(1e-300)), [], 2, ["rescale the data"], "diagnose"),
        "division by zero": (theta("1/0"), [], 2, [THETA, "division by zero"], "diagnose"),
        "duplicated key": (lambda p: bundled(p, text=(CONFIGS / "harmonic.yaml").read_text() + "model: {}\n"), [], 2,
                           ["duplicated key 'model'"], "diagnose"),
        "deep YAML": (text("model: " + nested(10_000) + "\n"), [], 2, ["nested deeper"], "diagnose"),
        "device foo": (override("adaptation.device=foo"), [], 2, ["adaptation.device"], "diagnose"),
        "seed 2**70": (override(f"data.seed={2**70}"), [], 2, ["data.seed"], "diagnose"),
        "NaN in the data": (frame(rows_set("x", [7], np.nan)), [], 2, ["column 'x'", "line 9"], "diagnose"),
    },
    "foreign content": {
        "file outside the config's folder is not echoed": (secret_outside, [], 2, ["secret.csv", "no column"]),
        "outside file, diagnose": (secret_outside, [], 2, ["secret.csv", "no column"], "diagnose"),
    },
    "nothing learnt": {
        "every candidate diverged (starts 300)": (diverging(300), [], 3, ["every one of the 4 candidates diverged",
                                                                          "result.json"]),
        "every candidate diverged (starts 1e6)": (diverging(1e6), [], 3, ["candidates diverged"]),
        "target constant to rounding": (frame(column_set("x_ddot", lambda f: 1.0 + np.arange(len(f)) * 1e-17)), [], 3,
                                        ["constant up to rounding"], "diagnose"),
        "acceleration constant to the estimate's precision (x = t^2/2)": (parabola, [], 3, [
            "'x_ddot'", "precision of the estimate", "tells nothing"]),
        "acceleration constant to the estimate's precision, diagnose": (parabola, [], 3, [
            "'x_ddot'", "precision of the estimate", "tells nothing"], "diagnose"),
        "initial guess 1e300, simulated outputs constant": (tanks(edit=guess(1e300)), [], 3, [
            "fitness rho (Eq. 19)", "initial_guess", "result.json"]),
        "initial guess 1e300, diagnosed by simulation": (tanks(edit=guess(1e300)), [], 3, [
            "do not correlate with the measured outputs", "initial_guess", "gap_report.json"], "diagnose"),
        "every hypothesis diverged, diagnosed by simulation (starts 300)": (tanks(edit=tank_starts(300)), [], 3, [
            "x1_dot: every hypothesis of the diagnosis diverged", "gap_report.json"], "diagnose"),
    },
}
if not CUDA:
    CORPUS["config values"]["device cuda on a CPU build"] = (override("adaptation.device=cuda"), [], 2,
                                                             ["adaptation.device", "'cuda'"])
CASES = [(kind, name) for kind, cases in CORPUS.items() for name in cases]


def hidden_leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".out") or ".tmp" in p.name)


@pytest.mark.parametrize("kind, name", CASES, ids=[f"{k}: {n}" for k, n in CASES])
def test_user_error(tmp_path, capsys, kind, name):
    build, extra, status, fragments, *command = CORPUS[kind][name]
    command = command[0] if command else "run"
    built = build(tmp_path)
    config, more = built if isinstance(built, tuple) else (built, [])
    out = tmp_path / "out"
    arguments = (["--no-tensorboard", *QUICK] if command == "run" else []) + ["-q"]  # the error alone on stderr
    arguments += [a.replace("{tmp}", str(tmp_path)) for a in extra + more]
    if "--out" not in arguments:
        arguments += ["--out", str(out)]
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main([command, str(config), *arguments])
    captured = capsys.readouterr()
    assert code == status, captured.err
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    assert "Traceback" not in captured.err and "SECRET" not in captured.err + captured.out
    for fragment in fragments:
        assert fragment in captured.err, (fragment, captured.err)
    assert not hidden_leftovers(tmp_path)
    if status == 2 or "tells nothing" in captured.err:  # bad input, or a record that tells nothing: nothing written
        assert sorted(p.name for p in tmp_path.iterdir()) == before and not out.exists()
        assert captured.out == ""
    elif command == "run":  # the run learnt nothing: no equation printed, the result written and complete
        assert "adapted:" not in captured.out
        result = json.loads((out / "result.json").read_text())
        assert result["version"] == 1 and result["equations"]
        if "diverged" in name:
            assert all(c["diverged"] for c in result["equations"][0]["ranking"])
    else:  # the diagnosis learnt nothing: no verdict printed, the report written, complete and saying so
        assert "verdict:" not in captured.out and (out / "report.md").is_file()
        report = json.loads((out / "gap_report.json").read_text())
        assert report["equations"]
        if "diverged" in name:
            assert all(c["diverged"] for c in report["equations"][0]["ranking"])


def test_corpus_size_and_outcome_table(capsys):
    """At least 100 cases; the table of outcomes by class (printed with -s)."""
    assert len(CASES) >= 100
    with capsys.disabled():
        counts = collections.Counter((kind, CORPUS[kind][name][2]) for kind, name in CASES)
        print("\ncase class | cases | exit status")
        for (kind, status), n in sorted(counts.items()):
            print(f"{kind} | {n} | {status}")


@ROOT_CANNOT_BE_REFUSED
def test_a_read_only_output_folder_is_refused(tmp_path, capsys):
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        assert main(["run", str(bundled(tmp_path)), "--out", str(folder / "out")]) == 2
    finally:
        folder.chmod(0o700)
    assert "--out" in capsys.readouterr().err


def test_a_second_run_into_a_folder_in_use_refuses(tmp_path, capsys):
    config, out = bundled(tmp_path), tmp_path / "out"
    with locked(out):
        assert main(["run", str(config), "--out", str(out), "--no-tensorboard", *QUICK]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and "another msam run" in err and not out.exists()
    assert main(["run", str(config), "--out", str(out), "--no-tensorboard", *QUICK]) == 0
    assert json.loads((out / "result.json").read_text())["version"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "out"]


def test_a_failed_run_removes_the_folders_it_created(tmp_path, capsys):
    config = bundled(tmp_path)
    assert main(["run", str(config), "--out", str(tmp_path / "new" / "deep" / "out"), "model.parameters.m=0"]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml"]


def test_a_failed_run_into_an_existing_folder_keeps_it(tmp_path, capsys):
    config, out = bundled(tmp_path), tmp_path / "out"
    assert main(["run", str(config), "--out", str(out), "--no-tensorboard", *QUICK]) == 0
    kept = (out / "result.json").read_bytes()
    assert main(["run", str(config), "--out", str(out), "model.parameters.m=0"]) == 2
    assert (out / "result.json").read_bytes() == kept


def test_an_internal_error_prints_one_line_and_logs_the_traceback(tmp_path, capsys, monkeypatch):
    import msam_torch.run.adapt

    def broken(*args, **kwargs):
        raise RuntimeError("an invariant broke\nover two lines")

    monkeypatch.setattr(msam_torch.run.adapt, "adapt", broken)
    config, out = bundled(tmp_path), tmp_path / "out"
    assert main(["run", str(config), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error" in err and "an invariant broke over two lines" in err
    log = Path(err.split("traceback in ")[1].split(";")[0])
    assert "Traceback" in log.read_text() and "RuntimeError" in log.read_text() and not out.exists()
    log.unlink()
    assert main(["run", str(config), "--out", str(out), "-v"]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_interrupt_is_one_line_and_status_130(tmp_path, capsys, monkeypatch):
    import msam_torch.run.adapt

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(msam_torch.run.adapt, "adapt", interrupted)
    assert main(["run", str(bundled(tmp_path)), "--out", str(tmp_path / "out")]) == 130
    assert capsys.readouterr().err == "interrupted\n" and not (tmp_path / "out").exists()


def test_help_and_version_exit_0(capsys):
    assert main(["--version"]) == 0 and "msam-torch" in capsys.readouterr().out
    assert main(["run", "--help"]) == 0 and "--out" in capsys.readouterr().out
