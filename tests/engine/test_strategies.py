"""Strategies behind registries: names and objects are interchangeable, the config schema follows
the registries, the options are interpreted once (msam_torch.run.plan), and the trainer's condition
numbers are an explicit switch."""
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest
import torch

from msam_torch.config.schema import ThetaRule, load_config
from msam_torch.data.derivatives import ESTIMATORS, Auto, Exact, SavitzkyGolay, estimate
from msam_torch.engine.step_rules import STEP_SIZES, Eq20, LineSearch
from msam_torch.engine.trainer import Algebraic
from msam_torch.engine.values import StepOptions
from msam_torch.errors import ConfigError
from msam_torch.run.adapt import adapt
from msam_torch.run.evaluators import EVALUATORS
from msam_torch.run.plan import config_schema, make_trainer, prepare
from tests.helpers import CONFIGS, QUICK, equation_data, measured_case, simulated


def outcome(result):
    return [(e.equation, e.exponents, e.adapted["fitness"]) for e in result.equations]


@pytest.mark.parametrize("key,registry", [("data.derivatives", ESTIMATORS), ("adaptation.step_size", STEP_SIZES),
                                          ("adaptation.evaluation", EVALUATORS)])
def test_unknown_names_are_config_errors_listing_the_registry(key, registry):
    """A name is looked up when the config is planned (before any data is read); a value that is
    neither a name nor an object fails on loading."""
    config = load_config(CONFIGS / "harmonic.yaml", [f"{key}=nonesuch"])
    with pytest.raises(ConfigError, match=rf"^{key}: .*unknown .* 'nonesuch' \(known: {', '.join(registry.names)}\)"):
        prepare(config)
    with pytest.raises(ConfigError, match=rf"^{key}: .*got int"):
        load_config(CONFIGS / "harmonic.yaml", [f"{key}=3"])
    with pytest.raises(ConfigError, match="adaptation.theta"):
        load_config(CONFIGS / "harmonic.yaml", ["adaptation.theta=nonesuch"])


@dataclass(frozen=True)
class Thinned:
    """A user's estimator: Savitzky-Golay on every sample with a fixed window of 21."""

    name: ClassVar[str] = "thinned"

    def estimate(self, t, y, order, where="signal"):
        return SavitzkyGolay(window=21).estimate(t, y, order, where)


def test_a_registered_estimator_joins_the_schema_and_runs_like_a_built_in(monkeypatch):
    monkeypatch.setitem(ESTIMATORS._factories, "thinned", Thinned)
    schema = config_schema()["$defs"]["DataConfig"]["properties"]["derivatives"]
    assert "thinned" in schema["enum"] and "savgol" in schema["enum"]
    assert config_schema()["$defs"]["AdaptationConfig"]["properties"]["evaluation"]["enum"] == ["algebraic", "simulation"]
    with pytest.raises(ConfigError, match="known: .*thinned"):
        prepare(load_config(CONFIGS / "harmonic.yaml", ["data.derivatives=wavelet"]))
    config, frame = measured_case("harmonic", every=4)
    config["data"] = {"time": "t", "columns": {"x": "x", "u": "u"}, "derivatives": "thinned"}
    named = adapt(config, QUICK, data=frame[["t", "x", "u"]])
    built_in = adapt(config, QUICK + ["data.derivatives=savgol", "data.window=21"], data=frame[["t", "x", "u"]])
    assert outcome(named) == outcome(built_in)
    assert named.data["derivatives"]["x"]["window"] == 21


def test_a_strategy_object_works_as_well_as_its_name():
    """``derivatives=SavitzkyGolay(window=15)`` and ``step_size=LineSearch()`` from Python give the
    same result, bit for bit, as naming them in the config; the config keeps the object and writes
    its name."""
    config, frame = measured_case("harmonic", every=4)
    config["data"] = {"time": "t", "columns": {"x": "x", "u": "u"}, "derivatives": "savgol"}
    named = adapt(config, QUICK + ["data.window=15", "adaptation.step_size=line_search"], data=frame[["t", "x", "u"]])
    given = adapt(config, QUICK, data=frame[["t", "x", "u"]], derivatives=SavitzkyGolay(window=15),
                  step_size=LineSearch())
    assert outcome(given) == outcome(named)
    assert given.data["derivatives"]["x"]["window"] == 15
    assert given.config["data"]["derivatives"] == "savgol" and given.config["adaptation"]["step_size"] == "line_search"
    in_config = adapt({**config, "data": {**config["data"], "derivatives": SavitzkyGolay(window=15)}}, QUICK,
                      data=frame[["t", "x", "u"]], step_size="line_search")
    assert outcome(in_config) == outcome(named)
    with pytest.raises(TypeError, match="unknown strategy option windw"):
        adapt(config, QUICK, data=frame[["t", "x", "u"]], windw=3)


def test_prepare_interprets_every_option_once():
    config = load_config(CONFIGS / "harmonic.yaml", ["adaptation.step_size=one", "adaptation.theta=varpro",
                                                     "data.derivatives=auto", "data.noise=0.01"])
    plan = prepare(config)
    assert plan.derivatives == SavitzkyGolay() and isinstance(plan.evaluator, Algebraic)
    assert plan.options.step_size == STEP_SIZES.create("one") and plan.options.theta is ThetaRule.VARPRO
    assert plan.dtype == torch.float64 and plan.device == torch.device("cpu")
    assert prepare(config.model_copy(update={"data": config.data.model_copy(update={"noise": 0.0})})).derivatives == Exact()
    assert prepare(config, in_memory=True, derivatives="auto").derivatives == SavitzkyGolay()  # no exact signals
    with pytest.raises(ConfigError, match="data.cutoff: a cut-off applies to derivatives: butterworth, not 'savgol'"):
        prepare(load_config(CONFIGS / "harmonic.yaml", ["data.derivatives=savgol", "data.cutoff=3"]))


def test_auto_estimates_like_savitzky_golay_outside_a_noise_free_simulation():
    """``estimate(..., 'auto')`` (what simulation-based evaluation asks for an initial state under the
    default ``derivatives: auto``) is Savitzky-Golay's estimate, not an unknown estimator."""
    s = simulated("harmonic")
    auto, savgol = estimate(s["t"], s["x"], 2, "auto"), estimate(s["t"], s["x"], 2, "savgol")
    assert auto.info == savgol.info
    assert all(np.array_equal(a, b) for a, b in zip(auto.values, savgol.values))
    assert Auto(window=9).choose(False) == SavitzkyGolay(window=9) and Auto().choose(True) == Exact()


def test_step_options_take_names_or_rules():
    assert StepOptions(step_size="line_search", theta="varpro") == StepOptions(step_size=LineSearch(), theta=ThetaRule.VARPRO)
    assert StepOptions().step_size == Eq20() and StepOptions().theta == "fixed"
    with pytest.raises(ConfigError, match="adaptation.step_size: unknown step-size rule 'huge'"):
        StepOptions(step_size="huge")


def test_condition_numbers_are_an_explicit_switch_that_leaves_the_fit_unchanged():
    """A listener alone does not switch on the eigendecompositions; ``diagnostics=True`` does, and
    the fit is the same bit for bit either way."""
    data, theta, theta_fixed, _ = equation_data("sode3", equation=0)
    plan = prepare(load_config(CONFIGS / "sode3.yaml", QUICK))
    seen = {}
    fits = []
    for diagnostics in (False, True):
        trainer = make_trainer(plan, diagnostics=diagnostics)
        trainer.add_callback("round_robin_step", lambda t, result, **p: seen.__setitem__(t.diagnostics, result.cond_scaled))
        fits.append(trainer.fit(data, theta.unsqueeze(0), theta_fixed.unsqueeze(0)))
    assert seen[False] is None
    assert seen[True].shape == fits[1].ranking_fitness.shape and bool(torch.isfinite(seen[True]).all())
    assert bool((seen[True] >= 1).all())  # a condition number
    for name in ("ranking_fitness", "ranking_gamma", "gamma", "theta", "theta_fixed"):
        assert torch.equal(getattr(fits[0], name), getattr(fits[1], name)), name


def test_simulation_evaluation_runs_with_the_default_auto_estimator(tmp_path):
    """Simulation-based evaluation estimates the unmeasured x_dot(0) from x under ``derivatives:
    auto`` (the default of the paper preset) exactly as under ``savgol``."""
    config, frame = measured_case("harmonic", every=10)
    frame[["t", "x", "u"]].to_csv(tmp_path / "record.csv", index=False)
    config["data"] = {"file": "record.csv", "time": "t", "columns": {"x": "x", "u": "u"}}
    quick = ["adaptation.evaluation=simulation", "adaptation.simulation.output=[x]", "adaptation.simulation.prefit_steps=0",
             "adaptation.round_robin_steps=1", "adaptation.refinement_steps=0", "adaptation.preset=paper"]
    auto = adapt(config, quick, base_dir=tmp_path)
    assert auto.config["data"]["derivatives"] == "auto"
    assert outcome(auto) == outcome(adapt(config, quick + ["data.derivatives=savgol"], base_dir=tmp_path))


class Counting:
    """A user's own evaluator: the algebraic one, counting the batches it evaluates and steps."""

    def __init__(self):
        self.calls = 0

    def evaluate(self, selection, state, options):
        self.calls += 1
        return Algebraic.evaluate(selection, state, options)

    def step(self, selection, state, current, options, conditions=True):
        self.calls += 1
        return Algebraic.step(selection, state, current, options, conditions)

    def starting_measures(self, data, theta, theta_fixed):
        return Algebraic.starting_measures(data, theta, theta_fixed)


def test_a_user_evaluator_passed_to_adapt_is_used():
    """An evaluator object that does not say it simulates takes the algebraic path, and every
    evaluation and step of the run goes through it: the same result as the built-in one."""
    config, frame = measured_case("harmonic", every=4)
    config["data"] = {"time": "t", "columns": {"x": "x", "u": "u"}, "derivatives": "savgol"}
    own = Counting()
    given = adapt(config, QUICK, data=frame[["t", "x", "u"]], evaluation=own)
    built_in = adapt(config, QUICK, data=frame[["t", "x", "u"]])
    assert own.calls >= 2 * len(given.equations)
    assert outcome(given) == outcome(built_in)
    assert not prepare(load_config(CONFIGS / "harmonic.yaml"), evaluation=own).simulates
    assert prepare(load_config(CONFIGS / "harmonic.yaml", ["adaptation.evaluation=simulation"])).simulates
