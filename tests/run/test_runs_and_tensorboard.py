"""Runs you can find again: each run without --out writes a new runs/<stem>/version_N; TensorBoard
of sode3 holds candidates named by their adjustments, a custom-scalars layout overlaying them per
measure and an hparams row (read back with tensorboard's EventAccumulator)."""
import os

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.custom_scalar import layout_pb2
from tensorboard.plugins.hparams import plugin_data_pb2

from msam_torch.cli.main import main
from tests.helpers import CONFIGS

QUICK = ["adaptation.round_robin_steps=2", "adaptation.refinement_steps=2"]


def test_runs_without_out_never_share_a_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        assert main(["run", str(CONFIGS / "harmonic.yaml"), "--no-tensorboard", *QUICK]) == 0
    assert sorted(p.name for p in (tmp_path / "runs" / "harmonic").iterdir()) == ["version_0", "version_1"]
    assert all((tmp_path / "runs" / "harmonic" / v / "result.json").is_file() for v in ("version_0", "version_1"))
    assert main(["run", str(CONFIGS / "harmonic.yaml"), "--no-tensorboard", "--out", "chosen", *QUICK]) == 0
    assert (tmp_path / "chosen" / "result.json").is_file()
    assert len(os.listdir(tmp_path / "runs" / "harmonic")) == 2


def test_sode3_tensorboard_has_named_candidates_a_layout_and_hparams(tmp_path):
    assert main(["run", str(CONFIGS / "sode3.yaml"), "--out", str(tmp_path), "--quiet", *QUICK]) == 0
    events = EventAccumulator(str(tmp_path / "tensorboard"), size_guidance={"scalars": 0, "tensors": 0})
    events.Reload()
    tags = set(events.Tags()["scalars"])
    # x1_dot = th1 x1 x3 + ...: candidate (x3, x3, x3) is the true structure, named by its adjustments
    assert "x1_dot/round_robin/fitness/x3-x3-x3" in tags
    assert len([t for t in tags if t.startswith("x1_dot/round_robin/fitness/")]) == 27
    assert not any("/c0" in t for t in tags)
    assert {f"x{i}_dot/adapted/fitness" for i in (1, 2, 3)} <= tags

    layout = layout_pb2.Layout()
    layout.ParseFromString(events.Tensors("custom_scalars__config__")[0].tensor_proto.string_val[0])
    charts = {c.title: c for category in layout.category for c in category.chart}
    assert {category.title for category in layout.category} == {"x1_dot", "x2_dot", "x3_dot"}
    assert "round_robin fitness" in charts and "refinement gamma_2" in charts
    assert list(charts["round_robin fitness"].multiline.tag) == ["^x3_dot/round_robin/fitness/"]

    content = events.PluginTagToContent("hparams")
    experiment = plugin_data_pb2.HParamsPluginData()
    experiment.ParseFromString(content["_hparams_/experiment"])
    names = {h.name for h in experiment.experiment.hparam_infos}
    assert {"adaptation.round_robin_steps", "adaptation.step_size", "data.system"} <= names
    assert {m.name.tag for m in experiment.experiment.metric_infos} == {
        f"x{i}_dot/adapted/{k}" for i in (1, 2, 3) for k in ("fitness", "sum_abs_error", "rho")}
    session = plugin_data_pb2.HParamsPluginData()
    session.ParseFromString(content["_hparams_/session_start_info"])
    assert session.session_start_info.hparams["adaptation.round_robin_steps"].number_value == 2
    assert session.session_start_info.hparams["data.system"].string_value == "sode3"
