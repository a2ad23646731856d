"""``msam run`` and ``msam diagnose`` give one answer: where run's adapted structure reads the law
the diagnosis names, run says so; where it does not, run states the diagnosis's reading and why
its own differs (:mod:`msam_torch.diagnosis.agreement`)."""
import pytest

from msam_torch import adapt, diagnose
from msam_torch.config.schema import Config
from msam_torch.diagnosis.agreement import agreement, changed, stated
from tests.diagnosis.test_parameter_terms import config as heat_config
from tests.diagnosis.test_parameter_terms import heated_body
from tests.diagnosis.test_time_units import tank


def test_the_same_law_in_another_form_agrees():
    """Torricelli outflow: run replaces the linear outflow by h|h|^-0.5, the diagnosis adds a copy
    beside it; both read total exponent 0.5 on h."""
    raw, frame = tank(1.0)
    config = Config(**raw)
    result = adapt(config, data=frame)
    (term, signal, _, total), = changed(result, config)["h_dot"]
    assert (term, signal) == ("h", "h") and total == pytest.approx(0.5, abs=0.1)
    lines = agreement(result, diagnose(config, data=frame), config)
    assert len(lines) == 1 and "Torricelli outflow: run's adapted structure reads the same law" in lines[0]


def test_a_compromise_of_run_is_stated_beside_the_diagnosis():
    """Natural convection beside a linear loss: run bends the linear loss a little (a compromise
    of both), the diagnosis keeps it and adds the 1.25 law: run states the diagnosis's reading."""
    config, frame = Config(**heat_config()), heated_body()
    result = adapt(config, data=frame)
    lines = agreement(result, diagnose(config, data=frame), config)
    assert lines[0].startswith("T_dot: diagnosis: gap explained by natural convection")
    assert "its model: T_dot =" in lines[0]
    assert "run's adapted structure differs (it adjusted T - Ta by |T - Ta|^" in lines[1]
    assert "adds a copy of it with its own exponent" in lines[1]


def test_a_simulated_system_is_not_diagnosed_again():
    config = Config(model=heat_config()["model"], data={"system": "harmonic"})
    assert stated(config, result=None) == []
