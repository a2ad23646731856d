"""Simulation-based evaluation: the true two-tank structure is a fixed point when only the lower
tank is measured; config errors, batched trials, input holds and in-memory data."""
import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from torchdiffeq import odeint

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.errors import ConfigError
from msam_torch.run.adapt import adapt, nominal_parameters
from msam_torch.run.adapt_simulated import prepare_group
from msam_torch.run.plan import prepare
from msam_torch.simulation.configured import load_records, output_states
from msam_torch.simulation.ode import Parameters, build_model
from msam_torch.simulation.solver import simulate
from tests.helpers import measured_case

TANKS = {
    "model": {
        "states": ["x1", "x2"], "inputs": ["u"], "parameters": {"k1": 0.05, "k2": 0.05, "k3": 0.05, "k4": 0.05},
        "equations": [
            {"target": "x1_dot", "components": [{"term": "x1", "theta": "-k1"}, {"term": "u", "theta": "k4", "adjustable": False}],
             "adjustments": ["abs(x1)"]},
            {"target": "x2_dot", "components": [{"term": "x1", "theta": "k2"}, {"term": "x2", "theta": "-k3"}],
             "adjustments": ["abs(x1)", "abs(x2)"]}]},
    "data": {"file": "tanks.csv", "time": "t", "columns": {"u": "u", "x2": "y"}},
    "adaptation": {"evaluation": "simulation", "simulation": {"output": ["x2"], "input_hold": "zoh", "prefit_steps": 8,
                                                              "initial_guess": {"x1": 3.0}},
                   "theta": "varpro", "normalize": "rms", "scaling": "gauss_newton", "step_size": "line_search",
                   "damping": 0.1, "round_robin_steps": 6, "refinement_steps": 8},
}


def torricelli_record(path: Path, n: int = 150, dt: float = 4.0, power: float = 0.5) -> None:
    """Two tanks with square-root outflow (level ** ``power``) under a random staircase input; only
    x2 is written (integrated sample by sample under the held input)."""
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(1.0, 5.0, n // 10 + 1), 10)[:n]
    t = torch.arange(n, dtype=torch.float64) * dt

    def rhs(level, x):  # the inflow ``level`` held over a sample
        x1, x2 = x[0].clamp_min(0), x[1].clamp_min(0)
        return torch.stack([-0.08 * x1**power + 0.05 * level, 0.08 * x1**power - 0.07 * x2**power])

    x = [torch.tensor([2.0, 3.0], dtype=torch.float64)]
    for k in range(n - 1):  # sample by sample, so that no solver stage reads the next sample's input
        x.append(odeint(lambda _, v: rhs(float(u[k]), v), x[-1], t[k:k + 2], method="rk4",
                        options={"step_size": dt / 8})[-1])
    x = torch.stack(x)
    pd.DataFrame({"t": t.numpy(), "u": u, "y": x[:, 1].numpy()}).to_csv(path, index=False)


@pytest.mark.slow
def test_true_structure_is_a_fixed_point_from_the_lower_tank_alone(tmp_path):
    """Two tanks with square-root outflow, only the lower level measured: started at the true
    exponents, simulation-based MSAM keeps the true structure (it wins the round robin with
    exponents within 0.05 of -0.5) while theta and the upper tank's initial level are re-estimated,
    and its free-run error falls far below the theta-retuned linear model's."""
    torricelli_record(tmp_path / "tanks.csv")
    config = copy.deepcopy(TANKS)
    for equation in config["model"]["equations"]:
        for component in equation["components"]:
            if component.get("adjustable", True):
                component["start"] = -0.5
    result = adapt(config, ["adaptation.round_robin_steps=3", "adaptation.refinement_steps=2",
                            "adaptation.simulation.refit_steps=2", "adaptation.damping=0.01"], base_dir=tmp_path)
    first, second = result.equations
    assert first.adjustments[0] == "abs(x1)"
    assert second.adjustments[:2] == ["abs(x1)", "abs(x2)"]
    exponents = [first.exponents[0], *second.exponents]
    assert all(abs(g + 0.5) < 0.05 for g in exponents), exponents
    rmse = result.data["simulation"][0]["free_run_rmse"]["train"]
    assert rmse["adapted"][0] < 0.05 * rmse["start"][0]


def test_simulation_config_errors_name_the_key(tmp_path):
    torricelli_record(tmp_path / "tanks.csv", n=20)
    bad = {**TANKS, "adaptation": {**TANKS["adaptation"], "simulation": {"output": ["y"]}}}
    with pytest.raises(ConfigError, match=r"adaptation.simulation.output\[0\]"):
        adapt(bad, base_dir=tmp_path)
    with pytest.raises(ConfigError, match="adaptation.simulation.method"):
        load_config({**TANKS, "adaptation": {"simulation": {"method": "dopri5"}}})


def test_trials_batch_parameter_sets(tmp_path):
    torricelli_record(tmp_path / "tanks.csv", n=30)
    config = load_config(TANKS, ["adaptation.simulation.prefit_steps=0", "adaptation.theta=fixed"])
    spec = to_spec(config.model)
    sets = [nominal_parameters(config, spec), {k: 2 * v for k, v in spec.parameters.items()}]
    prepared = prepare_group(prepare(config), spec.equations, sets, tmp_path)
    assert prepared.theta.shape == (2, 3) and prepared.theta_fixed.shape == (2, 1)
    torch.testing.assert_close(prepared.theta[1], 2 * prepared.theta[0])


def test_cubic_input_hold_follows_a_band_limited_input(tmp_path):
    """An input at 0.2 cycles per sample: between samples the cubic hold stays within 1 % of the
    sine where the linear one loses 19 % at the midpoints; an integrator x_dot = u simulated under
    the cubic hold follows the exact integral within 1 % of its amplitude (linear hold: 13 %)."""
    n, w = 400, 2 * np.pi * 0.2
    pd.DataFrame({"t": np.arange(n) * 1.0, "u": np.cos(w * np.arange(n)), "x": np.sin(w * np.arange(n)) / w}).to_csv(
        tmp_path / "integrator.csv", index=False)
    errors = {}
    for hold in ("linear", "cubic"):
        config = load_config({
            "model": {"states": ["x"], "inputs": ["u"], "parameters": {"c": 0.0},
                      "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "c"},
                                                                        {"term": "u", "theta": 1.0, "adjustable": False}],
                                     "adjustments": ["abs(x)"]}]},
            "data": {"file": "integrator.csv", "time": "t", "columns": {"u": "u", "x": "x"}, "derivatives": "interpolating_spline"},
            "adaptation": {"evaluation": "simulation", "simulation": {"output": ["x"], "input_hold": hold, "substeps": 4}}})
        spec = to_spec(config.model)
        model = build_model(spec, spec.equations)
        record, _ = load_records(config, spec, model, output_states(config, spec, model), tmp_path)
        inner = torch.arange(20, n - 20, dtype=torch.float64) + 0.5
        between = (record.at(inner)[:, 0] - torch.cos(w * inner)).abs().max()
        p = Parameters(torch.zeros(1, 1, dtype=torch.float64), torch.tensor([[1]]), torch.zeros(1, 1, dtype=torch.float64),
                       torch.ones(1, 1, dtype=torch.float64), torch.ones(1, 1, dtype=torch.float64))
        x = simulate(model, record, p, torch.zeros(1, 1, dtype=torch.float64), substeps=4)[0, :, 0]
        exact = torch.sin(w * record.t) / w
        drift = (x - exact)[20:-20]  # the edge's interpolation error is carried on as a constant
        errors[hold] = float(between), float((drift - drift.mean()).abs().max() * w)
    assert errors["cubic"][0] < 0.01 < 0.15 < errors["linear"][0]
    assert errors["cubic"][1] < 0.01 < 0.1 < errors["linear"][1]


@pytest.mark.parametrize("substeps", [1, 3])
def test_a_held_input_is_read_by_every_stage_of_its_own_steps(tmp_path, substeps):
    """An integrator x_dot = u under a held (zoh) random input: every Runge-Kutta step, its last
    stage at the next sample included, reads the input held over that step, so the run is the
    exact running sum of u dt (a last stage reading the next sample's input is off by up to
    dt/8 of an input step per sample)."""
    rng = np.random.default_rng(3)
    u = rng.uniform(-1.0, 1.0, 200)
    pd.DataFrame({"t": np.arange(200) * 0.5, "u": u, "x": np.concatenate([[0.0], np.cumsum(u[:-1]) * 0.5])}).to_csv(
        tmp_path / "held.csv", index=False)
    config = load_config({
        "model": {"states": ["x"], "inputs": ["u"], "parameters": {"c": 0.0},
                  "equations": [{"target": "x_dot", "components": [{"term": "x", "theta": "c"},
                                                                    {"term": "u", "theta": 1.0, "adjustable": False}],
                                 "adjustments": ["abs(x)"]}]},
        "data": {"file": "held.csv", "time": "t", "columns": {"u": "u", "x": "x"}},
        "adaptation": {"evaluation": "simulation", "simulation": {"output": ["x"], "input_hold": "zoh"}}})
    spec = to_spec(config.model)
    model = build_model(spec, spec.equations)
    record, _ = load_records(config, spec, model, output_states(config, spec, model), tmp_path)
    p = Parameters(torch.zeros(1, 1, dtype=torch.float64), torch.tensor([[1]]), torch.zeros(1, 1, dtype=torch.float64),
                   torch.ones(1, 1, dtype=torch.float64), torch.ones(1, 1, dtype=torch.float64))
    x = simulate(model, record, p, torch.zeros(1, 1, dtype=torch.float64), substeps=substeps)[0, :, 0]
    torch.testing.assert_close(x, record.outputs[0], rtol=0, atol=1e-9)


def test_a_diagnosis_whose_candidates_all_diverged_says_so_and_blames_no_candidate_set():
    """Every candidate of an equation diverged in the adaptation by simulation: the equation is
    inconclusive because nothing was fitted, with the damped step to try (before, "the candidates
    do not express" the gap, which no fit had tested)."""
    from msam_torch.diagnosis import DiagnoseOptions, Verdict
    from msam_torch.diagnosis.stages.simulated import _equation_gap
    from msam_torch.run.result import EquationResult

    config = load_config(TANKS)
    plan, equation = prepare(config), to_spec(config.model).equations[1]
    n = len(equation.components)
    adapted = EquationResult(equation.target, "", "", [None] * n, [None] * n, [0.0] * n, {}, {},
                             [{"adjustments": ["abs(x1)", None], "diverged": True},
                              {"adjustments": [None, "abs(x2)"], "diverged": True}], 2)
    where = {"flagged_fraction": 0.0, "split_explained": 0.0, "time_windows": [], "regions": []}
    gap = _equation_gap(equation, adapted, [0.05, -0.05], [0.05, -0.05], True, torch.tensor([1.0, 0.5, 0.4]), 1.0,
                        where, {"failed": []}, DiagnoseOptions(), plan)
    assert gap.verdict_kind is Verdict.INCONCLUSIVE and not gap.significant and gap.effect is None
    reasons = gap.checks["reasons"]
    assert "every candidate diverged" in reasons[0] and "adaptation.damping" in reasons[1]
    assert not any("do not express" in r for r in reasons)


@pytest.mark.slow
def test_a_measured_record_judged_by_simulation_gets_a_step_that_keeps_the_candidates(tmp_path):
    """The measured preset's damped line-search step where candidates are simulated (the harmonic
    oscillator's record as a file, only x compared): no candidate leaves the exponents' range and
    the winner fits far better than under the undamped dM-scaled step with Eq. 20's mu, which marks
    four candidates diverged and leaves the rest at gamma = 0."""
    config, frame = measured_case("harmonic", every=4)
    frame[["t", "x", "u"]].to_csv(tmp_path / "record.csv", index=False)
    config["data"] = {"file": "record.csv", "time": "t", "columns": {"x": "x", "u": "u"}}
    quick = ["adaptation.evaluation=simulation", "adaptation.simulation.output=[x]",
             "adaptation.round_robin_steps=5", "adaptation.refinement_steps=10"]
    damped = adapt(config, quick, base_dir=tmp_path).equations[0]
    undamped = adapt(config, quick + ["adaptation.scaling=dm", "adaptation.step_size=eq20", "adaptation.damping=0"],
                     base_dir=tmp_path).equations[0]
    assert damped.diverged == 0 and undamped.diverged == 4
    assert undamped.exponents[:2] == [0.0, 0.0]
    assert damped.adapted["fitness"] > 20 * undamped.adapted["fitness"]
