"""A parameter may appear in a term or an adjustment (``T - Ta`` with ``Ta`` the ambient
temperature, a parameter): it reads its nominal value there, and may be declared in
``model.quantities`` like a signal, so the catalogue reads ``T - Ta`` as a temperature difference."""
import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp

from msam_torch import adapt
from msam_torch.config.schema import ModelConfig
from msam_torch.config.to_spec import to_spec
from msam_torch.diagnosis import Verdict, diagnose
from msam_torch.errors import ConfigError

AMBIENT, H, H_NC, C = 293.0, 0.5, 0.08, 10.0


def heated_body():
    """C T' = P - h (T - Ta) - h_nc (T - Ta)^1.25: a body losing heat by natural convection."""
    t = np.linspace(0.0, 2000.0, 3001)
    power = 60 + 40 * np.sin(2 * np.pi * t / 400) + 20 * np.sin(2 * np.pi * t / 130 + 1)
    rhs = lambda s, T: [(np.interp(s, t, power) - H * (T[0] - AMBIENT) - H_NC * abs(T[0] - AMBIENT) ** 1.25) / C]
    temperature = solve_ivp(rhs, (0, 2000), [300.0], t_eval=t, rtol=1e-10, atol=1e-10, max_step=1).y[0]
    temperature += 0.002 * temperature.std() * np.random.default_rng(0).standard_normal(t.size)
    return pd.DataFrame({"t": t, "T": temperature, "P": power})


def config(**model):
    return {"model": {"states": ["T"], "inputs": ["P"], "parameters": {"C": C, "h": H, "Ta": AMBIENT},
                      "quantities": {"T": "temperature", "Ta": "temperature", "P": "power"},
                      "equations": [{"target": "T_dot", "components": [
                          {"term": "T - Ta", "theta": "-h/C"}, {"term": "P", "theta": "1/C", "adjustable": False}],
                          "adjustments": ["abs(T - Ta)"]}], **model},
            "data": {"time": "t", "columns": {"T": "T", "P": "P"}}}


def test_a_parameter_in_a_term_reads_its_value():
    spec = to_spec(ModelConfig(**config()["model"]))
    term = spec.equations[0].components[0].term
    assert term.names == {"T"} and dict(term.constants) == {"Ta": AMBIENT}
    assert float(term({"T": 300.0})) == pytest.approx(7.0)


def test_a_parameter_in_a_term_works_in_diagnose_and_run():
    frame = heated_body()
    gap = diagnose(config(), data=frame).equations[0]
    assert gap.verdict_kind is Verdict.EXPLAINED and gap.effect == "natural convection"
    assert gap.naming["total_exponent"] == pytest.approx(1.25, abs=0.2)
    result = adapt(config(), data=frame)
    exponent = result.equations[0].exponents[0]
    assert 0.0 < exponent < 0.5  # the loss bends the right way: above 1 in T - Ta
    sympy_text = str(result.model().to_sympy()[0])
    assert "293.0" in sympy_text and "Ta" not in sympy_text  # exported with the parameter's value


def test_an_unknown_name_in_a_term_is_still_an_error():
    bad = config()
    bad["model"]["equations"][0]["components"][0]["term"] = "T - Tb"
    with pytest.raises(ConfigError, match=r"components\[0\]\.term.*unknown name 'Tb'"):
        to_spec(ModelConfig(**bad["model"]))
    bad = config()
    bad["model"]["quantities"]["Tb"] = "temperature"
    with pytest.raises(ConfigError, match="model.quantities.Tb.*not a state, an input, a derivative of one or a parameter"):
        to_spec(ModelConfig(**bad["model"]))
