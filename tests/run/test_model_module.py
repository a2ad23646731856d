"""The adapted model as an ``nn.Module`` (msam_torch.run.state_model): free-run with torchdiffeq, the
sympy form of the printed equation, tables, state_dict, dtype."""
import copy
import dataclasses
import re

import numpy as np
import pytest
import sympy
import torch
from sympy.parsing.sympy_parser import implicit_multiplication_application, parse_expr, standard_transformations
from torchdiffeq import odeint

from msam_torch import adapt
from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.errors import ConfigError
from msam_torch.model.notation import format_component
from msam_torch.simulation.free_run import free_runs


@pytest.fixture(scope="module")
def harmonic():
    result = adapt("configs/harmonic.yaml")
    raw = copy.deepcopy(result.config)
    raw["adaptation"]["simulation"]["output"] = ["x", "x_dot"]
    config = load_config(raw)
    run = free_runs(config, to_spec(config.model), {"adapted": result.equations}, "configs",
                    records=("train",))["train"]
    return result, run


@pytest.mark.slow
def test_odeint_free_run_matches_the_package_free_run(harmonic):
    result, run = harmonic
    model = result.model().with_inputs(run.record.t, run.record.external)
    assert model.states == ("x", "x_dot") and model.inputs == ("u",)
    step = run.record.t[1] - run.record.t[0]
    states = odeint(model, run.states[0, 0], run.record.t, method="rk4", options={"step_size": step})
    assert run.states[0].abs().max() > 0.1
    assert (states - run.states[0]).abs().max() < 1e-8
    again = model.simulate(run.record.t, {"u": run.record.external[:, 0]}, run.states[0, 0])
    assert (again - run.states[0]).abs().max() < 1e-8


def _printed(text: str):
    """The printed equation ``y = -26.13 x_dot|x_dot|^1.000 + ...`` read by sympy."""
    target, rhs = text.split(" = ")
    rhs = re.sub(r"\|([^|]+)\|\^([0-9.]+)", r" Abs(\1)**\2 ", rhs).replace("sgn(", "sign(")
    rhs = parse_expr(rhs, transformations=standard_transformations + (implicit_multiplication_application,))
    return sympy.Symbol(target), rhs


@pytest.mark.parametrize("stage", ["adapted", "start", "retuned", "adapted_retuned"])
def test_to_sympy_round_trips_the_printed_equation(harmonic, stage):
    result, _ = harmonic
    entry = result.equations[0]
    printed = {"adapted": entry.equation, "start": None, "retuned": entry.theta_tuning["retuned"]["equation"],
               "adapted_retuned": entry.theta_tuning["adapted_retuned"]["equation"]}[stage]
    (equation,) = result.model(stage).to_sympy()
    if printed is None:  # the nominal start: theta = -c/m, -k/m, 1/m of the config
        x, x_dot, u = sympy.symbols("x x_dot u")
        coefficients = [float(equation.rhs.coeff(s)) for s in (x_dot, x, u)]
        assert coefficients == pytest.approx([-9800 / 375, -130000 / 375, 1 / 375], rel=1e-12)
        assert equation.rhs.free_symbols == {x, x_dot, u}
        return
    target, rhs = _printed(printed)
    assert equation.lhs == target
    assert equation.rhs.free_symbols == rhs.free_symbols
    assert len(sympy.Add.make_args(equation.rhs)) == len(sympy.Add.make_args(rhs))
    rng = np.random.default_rng(0)
    names = sorted(rhs.free_symbols, key=str)
    ours, theirs = sympy.lambdify(names, equation.rhs), sympy.lambdify(names, rhs)
    size = sympy.lambdify(names, sum(abs(a) for a in sympy.Add.make_args(rhs)))
    for _ in range(20):  # printed to 4 significant digits (theta) and 3 decimals (exponents)
        point = rng.uniform(-3, 3, len(names))
        assert abs(ours(*point) - theirs(*point)) < 1e-3 * size(*point)
    latex = result.model(stage).to_latex()
    assert "\\left|" in latex or stage in ("retuned",)
    assert latex.startswith("\\ddot{x} = ") and "x_{" not in latex  # derivatives as dots, not subscripts


def test_table_state_dict_and_dtype(harmonic):
    result, run = harmonic
    model = result.model()
    frame = model.to_frame()
    assert list(frame["term"]) == ["x_dot", "x", "u"]
    assert list(frame["function"][:2]) == ["abs(x_dot)", "abs(x)"]
    assert frame["exponent"][:2].tolist() == pytest.approx([1.0, 2.0], abs=1e-3)
    assert frame["theta"].tolist() == pytest.approx(result.equations[0].theta, rel=1e-12)
    start = result.model("start")
    start.load_state_dict(model.state_dict())
    x = run.states[0, ::100]
    inputs = run.record.external[::100]
    assert torch.allclose(start.predict(run.record.t[::100], x, inputs), model.predict(run.record.t[::100], x, inputs))
    single = model.to(torch.float32).with_inputs(run.record.t, run.record.external)
    rate = single(torch.tensor(0.5), run.states[0, 500].float())
    assert rate.dtype == torch.float32
    exact = model.double()(torch.tensor(0.5, dtype=torch.float64), run.states[0, 500]).detach()
    assert rate.double().detach().tolist() == pytest.approx(exact.tolist(), rel=1e-5)


def test_unknown_stage_and_missing_inputs_name_the_place(harmonic):
    result, _ = harmonic
    with pytest.raises(ConfigError, match="stage"):
        result.model("accepted")
    with pytest.raises(ConfigError, match="with_inputs"):
        result.model()(torch.tensor(0.0), torch.zeros(2, dtype=torch.float64))


def test_torch_export_gives_the_same_rates(harmonic):
    result, run = harmonic
    model = result.model().with_inputs(run.record.t, run.record.external)
    t, x = torch.tensor(0.7, dtype=torch.float64), run.states[0, 300]
    exported = torch.export.export(model, (t, x)).module()
    assert torch.allclose(exported(t, x), model(t, x), rtol=1e-14, atol=0)


def test_a_run_judged_by_simulation_gives_its_retuned_stage(harmonic):
    """A simulation run records its retuned theta under data.simulation and has no theta_tuning."""
    result, _ = harmonic
    retuned = [-3.5, -12.0, 0.0025]
    equations = [dataclasses.replace(e, theta_tuning={}) for e in result.equations]
    simulated = dataclasses.replace(result, equations=equations, data={
        **result.data, "simulation": [{"retuned_theta": {"x_ddot": retuned}}]})
    assert simulated.model("retuned").to_frame()["theta"].tolist() == retuned
    assert simulated.model().to_frame()["theta"].tolist() == pytest.approx(result.equations[0].theta, rel=1e-12)
    with pytest.raises(ConfigError, match="adapted_retuned"):
        simulated.model("adapted_retuned")


@pytest.mark.slow
def test_print_shows_the_equations_without_a_diagnosis_unadjusted_copies(harmonic):
    """``print(model)`` shows each equation to four digits (before: ``StateModel()``); a diagnosis's
    model prints no switched-off copy, zero constant or ``|1|^0`` factor (only its four terms)."""
    from msam_torch.diagnosis import DiagnoseOptions, diagnose

    result, _ = harmonic
    model = result.model("adapted")
    printed = str(model)
    assert printed.startswith("StateModel(x_ddot = ") and printed.endswith(")")
    rhs = sympy.sympify(printed[len("StateModel(x_ddot = "):-1])
    (equation,) = model.to_sympy()
    names = sorted(equation.rhs.free_symbols, key=str)
    ours, shown = sympy.lambdify(names, equation.rhs), sympy.lambdify(names, rhs)
    for point in np.random.default_rng(0).uniform(-3, 3, (10, len(names))):
        assert shown(*point) == pytest.approx(ours(*point), rel=1e-3)
    report = diagnose("configs/msd_coulomb.yaml", options=DiagnoseOptions(bootstrap=0, free_run=False))
    shown = str(report.model("adapted"))
    assert "sign(0)" not in shown and "Abs(1)" not in shown
    assert len(sympy.Add.make_args(sympy.sympify(shown.split(" = ")[1][:-1]))) == 4  # u, x, x_dot and the effect


def test_an_exponent_that_rounds_to_zero_prints_without_a_sign():
    spec = to_spec(load_config({"model": {
        "states": ["i"], "inputs": ["v"], "parameters": {},
        "equations": [{"target": "i_dot", "components": [{"term": "i", "theta": -1.0}], "adjustments": ["abs(i)"]}]}}).model)
    assert format_component(spec.equations[0], 0, 0, -0.0001) == "i|i|^0.000"
    assert format_component(spec.equations[0], 0, 0, -0.0006) == "i|i|^-0.001"
