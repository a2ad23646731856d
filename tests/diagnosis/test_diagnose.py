"""Sim-to-real gap diagnosis: weak form, catalogue, simulation, and one case end to end."""
import json
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pandas as pd
import pytest
import torch

from msam_torch.cli.main import main
from msam_torch.config.schema import DataConfig, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import build_dataset
from msam_torch.data.systems import SYSTEMS, WITHHELD
from msam_torch.data.systems import measure as simulate_true
from msam_torch.diagnosis import DiagnoseOptions, Verdict, diagnose
from msam_torch.diagnosis.catalogue.entries import NOT_CATALOGUED, name_effect
from msam_torch.engine.weak_form import TestFunctions as Bumps
from msam_torch.simulation.equations import EquationModel
from msam_torch.simulation.equations import simulate_equations as simulate

FAST = DiagnoseOptions(bootstrap=6, steps=20)


def short(name, samples=600, t_end=15.0):
    return replace(SYSTEMS[name], samples=samples, t_end=t_end)


@lru_cache(maxsize=None)
def true_signals(name):
    return {k: v.numpy() for k, v in simulate_true(short(name), rtol=1e-7, atol=1e-9).items()}


def case_data(case, noise=0.0, scale=1.0):
    """Training and held-out datasets of a withheld-effect case on a short record (x in ``1/scale`` units)."""
    w = WITHHELD[case]
    spec = to_spec(load_config({"model": w.model}).model)
    rng = np.random.default_rng(0)
    out = []
    for name in (w.system, w.held_out):
        system = short(name)
        sim = true_signals(name)
        measured = {k: scale * sim[k] * (1 if k not in system.inputs else 1 / scale) +
                    (0 if k in system.inputs else noise * sim[k].std() * rng.standard_normal(sim[k].size))
                    for k in system.measured}
        out.append(build_dataset(sim["t"], measured, DataConfig(derivatives="savgol"), spec, {"source": name},
                                 torch.float64))
    return w, out


def test_weak_form_integrates_by_parts():
    t = torch.linspace(0, 10, 1001, dtype=torch.float64)
    tests = Bumps.build(t, half_width=40)
    x = torch.sin(1.3 * t)
    # int phi x'' dt = int phi'' x dt, with x'' = -1.69 sin
    scale = tests.integrate_signal(x, 0).abs().max()
    assert (tests.integrate_signal(x, 2) - tests.integrate_signal(-1.69 * x, 0)).abs().max() < 1e-3 * scale
    assert (-tests.integrate_signal(x, 1) - tests.integrate_signal(1.3 * torch.cos(1.3 * t), 0)).abs().max() < 1e-3 * scale


def test_catalogue_names_by_role_and_exponent():
    spec = to_spec(load_config({"model": WITHHELD["msd_coulomb"].model}).model)
    eq = spec.equations[0]  # components x_dot, x, u; adjustments abs(x_dot), abs(x)
    assert name_effect(eq, 0, 0, -0.97, -0.5, -0.5) == "Coulomb friction"
    assert name_effect(eq, 0, 0, 1.1, -0.5, -0.5) == "quadratic drag"
    assert name_effect(eq, 0, 0, 0.5, -0.5, -0.5) == "power-law damping"
    assert name_effect(eq, 1, 1, 2.0, -1.0, -4.0) == "hardening cubic stiffness"
    assert name_effect(eq, 1, 1, 2.0, 1.0, -4.0) == "softening cubic stiffness"
    assert name_effect(eq, 0, 1, 2.0, -1.0, -0.5) == "van der Pol-type damping"
    assert name_effect(eq, 0, 0, -0.3, -1.0, -0.5) == "power-law damping"  # total exponent 0.7 on x_dot
    assert name_effect(eq, 0, 0, -0.7, -1.0, -0.5) == NOT_CATALOGUED  # 0.3: neither Coulomb (0 +- 0.2) nor a damping law
    assert name_effect(eq, 0, 0, 1.5, -1.0, -0.5) == NOT_CATALOGUED  # total 2.5: beyond drag's 2 +- 0.2
    assert name_effect(eq, 1, 0, 1.0, -1.0, -4.0) == NOT_CATALOGUED


def test_simulate_reproduces_the_true_linear_system():
    truth = {k: torch.as_tensor(v) for k, v in true_signals("msd_linear").items()}
    spec = to_spec(load_config({"model": WITHHELD["msd_linear"].model}).model)
    eq = spec.equations[0]
    model = EquationModel.starting(eq, spec.theta(eq))
    out = simulate(spec, [model], truth["t"], {"u": truth["u"]}, {"x": 0.0, "x_dot": 0.0})
    error = (out["x"][0] - truth["x"]).abs().max() / truth["x"].abs().max()
    assert error < 1e-3  # linear interpolation of the input between samples


def test_simulate_marks_a_diverging_member_without_spoiling_the_batch():
    truth = {k: torch.as_tensor(v) for k, v in true_signals("msd_linear").items()}
    spec = to_spec(load_config({"model": WITHHELD["msd_linear"].model}).model)
    eq = spec.equations[0]
    theta = torch.stack([spec.theta(eq), torch.tensor([3.0, 4.0, 1.0], dtype=torch.float64)])  # unstable damping
    out = simulate(spec, [EquationModel.starting(eq, theta)], truth["t"], {"u": truth["u"]}, {"x": 0.0, "x_dot": 0.0},
                   scale={"x": 3.0, "x_dot": 6.0})
    assert torch.isnan(out["x"][1]).all()
    assert (out["x"][0] - truth["x"]).abs().max() < 1e-3


@pytest.mark.slow
def test_diagnosis_end_to_end_report(tmp_path):
    w, (train, held_out) = case_data("msd_coulomb")
    report = diagnose({"model": w.model}, data=train, validation=held_out, options=FAST)
    assert report.verdict_kind is Verdict.EXPLAINED and report.verdict == "gap explained by Coulomb friction"
    gap = report.equations[0]
    assert gap.verdict_kind is Verdict.EXPLAINED and gap.effect == "Coulomb friction"
    assert abs(gap.exponent + 1) < 0.2 and gap.confidence["win_frequency"] >= 0.5
    free = report.measures["free_run"]["held_out"]["nrmse"]
    assert free["adapted"] * 5 < free["start"] and free["adapted"] < free["retuned"]
    assert "Coulomb friction" in str(report)
    path = report.save(tmp_path)
    saved = json.loads(path.read_text())
    assert saved["version"] == 1 and saved["verdict"] == report.verdict and saved["verdict_kind"] == "explained"
    assert saved["equations"][0]["verdict"] == gap.verdict and saved["equations"][0]["verdict_kind"] == "explained"
    for key in ("target", "significant", "verdict", "effect", "confidence", "improvement", "ranking", "where",
                "start_equation", "retuned_equation", "adapted_equation", "components"):
        assert key in saved["equations"][0]
    for key in ("one_step", "free_run"):
        assert set(saved["measures"][key]) == {"train", "held_out"}
    assert set(saved["measures"]["free_run"]["held_out"]["gap_closed_interval"]) == {"retuning", "effect", "effect_on_retuned"}
    markdown = (tmp_path / "report.md").read_text()
    assert "gap explained by Coulomb friction" in markdown
    for png in ("free_run_held_out.png", "free_run_train.png", "x_ddot_residual_time.png", "x_ddot_residual_vs_state.png"):
        assert (tmp_path / png).stat().st_size > 1000 and f"({png})" in markdown


def test_null_case_reports_no_significant_gap():
    w, (train, held_out) = case_data("msd_linear", noise=0.01)
    report = diagnose({"model": w.model, "data": {"parametric_error": 0.5, "seed": 3}}, data=train, validation=held_out,
                      options=replace(FAST, free_run=False))
    assert report.verdict_kind is Verdict.NO_GAP and report.verdict == "no significant gap"
    assert report.equations[0].verdict_kind is Verdict.NO_GAP
    assert report.equations[0].effect is None


def test_units_do_not_change_the_selection():
    w, (train, held_out) = case_data("msd_hardening")
    _, (train_mm, held_mm) = case_data("msd_hardening", scale=1000.0)
    options = replace(FAST, free_run=False, bootstrap=0)
    a = diagnose({"model": w.model}, data=train, validation=held_out, options=options).equations[0]
    b = diagnose({"model": w.model}, data=train_mm, validation=held_mm, options=options).equations[0]
    assert a.verdict_kind is b.verdict_kind is Verdict.EXPLAINED
    assert a.verdict == b.verdict == "gap explained by hardening cubic stiffness"
    assert a.exponent == pytest.approx(b.exponent, abs=1e-3)


@pytest.mark.slow
def test_cli_diagnose_with_data_files(tmp_path, capsys):
    w = WITHHELD["msd_quadratic_drag"]
    for name, file in ((w.system, "train.csv"), (w.held_out, "held.csv")):
        sim = true_signals(name)
        pd.DataFrame({"time": sim["t"], "pos": sim["x"], "force": sim["u"]}).to_csv(
            tmp_path / file, index=False)
    config = {"model": w.model, "data": {"time": "time", "columns": {"x": "pos", "u": "force"}, "derivatives": "savgol",
                                         "file": "unused.csv"}}
    (tmp_path / "c.yaml").write_text(json.dumps(config))
    code = main(["diagnose", str(tmp_path / "c.yaml"), "--data", str(tmp_path / "train.csv"),
                 "--validate", str(tmp_path / "held.csv"), "--out", str(tmp_path / "out")])
    assert code == 0
    assert "gap explained by quadratic drag" in capsys.readouterr().out
    assert (tmp_path / "out" / "gap_report.json").exists()


def test_cli_reports_a_bad_file_without_traceback(tmp_path, capsys):
    w = WITHHELD["msd_quadratic_drag"]
    config = {"model": w.model, "data": {"time": "time", "columns": {"x": "pos", "u": "force"}, "derivatives": "savgol",
                                         "file": "missing.csv"}}
    (tmp_path / "c.yaml").write_text(json.dumps(config))
    assert main(["diagnose", str(tmp_path / "c.yaml")]) == 2
    assert "missing.csv" in capsys.readouterr().err


def test_localise_finds_where_a_clearance_spring_engages():
    from msam_torch.diagnosis.stages import localise

    generator = torch.Generator().manual_seed(0)
    x = 4 * torch.rand(1500, generator=generator, dtype=torch.float64) - 2
    v = torch.randn(1500, generator=generator, dtype=torch.float64)
    y = -4 * x - 0.5 * v - 6 * torch.sign(x) * torch.relu(x.abs() - 0.6)
    y = y + 0.05 * torch.randn(1500, generator=generator, dtype=torch.float64)
    regions, flagged, residual, explained = localise.localise(torch.stack([x, v], -1), y, {"x": x, "x_dot": v})
    best = regions[0]
    assert best.signal == "x" and best.kind == "abs_gt" and abs(best.value - 0.6) < 0.1
    truth = x.abs() > 0.6
    assert (flagged & truth).sum() / (flagged | truth).sum() > 0.9 and explained > 0.9
    assert residual[x.abs() < 0.6].abs().max() < 0.3  # the starting structure holds inside the clearance


def test_the_regimes_residuals_are_those_of_separate_weighted_fits():
    """The batched residual sums of squares of localise (normal equations of every rule from one
    product, residuals from the solutions) are those of each rule's own weighted least-squares fit."""
    from msam_torch.diagnosis.stages.localise import _sse

    generator = torch.Generator().manual_seed(1)
    design = torch.randn(800, 4, generator=generator, dtype=torch.float64)
    y = design @ torch.tensor([1.0, -2.0, 0.5, 3.0], dtype=torch.float64) + torch.randn(800, generator=generator,
                                                                                    dtype=torch.float64)
    weights = (torch.rand(5, 800, generator=generator, dtype=torch.float64) > 0.4).to(torch.float64)
    expected = []
    for w in weights:
        rows = w.bool()
        x = torch.linalg.lstsq(design[rows], y[rows].unsqueeze(-1)).solution.squeeze(-1)
        expected.append(float(((y[rows] - design[rows] @ x) ** 2).sum()))
    assert _sse(design, y, weights).tolist() == pytest.approx(expected, rel=1e-10)


def test_a_diverged_adapted_run_closes_none_of_the_re_fitted_models_error():
    """The effect's share of the theta re-fitted model's free-run error: 80 % where the adapted run
    is five times closer, 0 (not negative) where it diverged."""
    from msam_torch.diagnosis.compare.measures import closure
    shares = closure(torch.tensor([1.0, 1.0]), torch.tensor([0.5, 0.5]), torch.tensor([0.1, float("inf")]))
    assert shares["effect_on_retuned"].tolist() == pytest.approx([0.8, 0.0])
