"""Several effects in turn: a mass-spring-damper with two withheld effects gets both, in either
order (cubic stiffness first, or quadratic drag first, found beside a provisional power law); with
one, exactly one; with none, none. And the adapted structure written as a starting model computes
the adapted model's rate."""
import re
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
import torch

from msam_torch.cli.main import main
from msam_torch.config.schema import DataConfig, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import build_dataset
from msam_torch.data.systems import WITHHELD as SUITE
from msam_torch.data.systems import System, measure, multisine
from msam_torch.diagnosis import DiagnoseOptions, EquationGap, GapReport, Verdict, diagnose
from msam_torch.diagnosis.effects.adapted import adapted_components
from msam_torch.diagnosis.effects.hypotheses import encode, enumerate_hypotheses, extended_equation, offset_testable
from msam_torch.diagnosis.effects.multi import in_turn
from msam_torch.errors import ConfigError
from msam_torch.simulation.equations import EquationModel
from msam_torch.zoo import SHARE_FLOOR, generate_pair, score
from msam_torch.zoo.effects import separable

MODEL = SUITE["msd_coulomb"].model  # the withheld-effect suite's mass-spring-damper starting model
EXCITATIONS = (multisine((0.4, 0.7, 1.1, 1.5, 1.9, 2.4, 3.0, 3.7), 2.5), multisine((0.5, 0.9, 1.3, 1.7, 2.2, 2.8), 2.2))
WITHHELD = {  # name -> (catalogue names, force the starting model lacks)
    "coulomb_and_cubic": ({"Coulomb friction", "hardening cubic stiffness"},
                          lambda x, v: 0.6 * torch.tanh(v / 0.01) + 2.0 * x**3),
    "drag_and_cubic": ({"quadratic drag", "hardening cubic stiffness"}, lambda x, v: 0.4 * v * v.abs() + 2.0 * x**3),
    "offset_and_cubic": ({"constant offset", "hardening cubic stiffness"},
                         lambda x, v: 2.0 * x**3 - 0.3 + 0.0 * v),
    "coulomb": ({"Coulomb friction"}, lambda x, v: 0.6 * torch.tanh(v / 0.01)),
    "none": (set(), lambda x, v: 0.0 * x),
}
TOTAL_EXPONENT = {"Coulomb friction": 0.0, "hardening cubic stiffness": 3.0, "quadratic drag": 2.0}  # on the effect's signal
OPTIONS = DiagnoseOptions(bootstrap=8, steps=20, max_effects=3)  # the loop is opt-in


def _rhs(force):
    def rhs(t, s, p, u):
        x, v = s[..., 0], s[..., 1]
        return torch.stack([v, -0.5 * v - 4.0 * x - force(x, v) + u["u"]], -1)
    return rhs


def datasets(case: str, noise: float = 0.01):
    spec = to_spec(load_config({"model": MODEL}).model)
    rng = np.random.default_rng(0)
    out = []
    for u in EXCITATIONS:
        system = System(("x", "x_dot"), {}, _rhs(WITHHELD[case][1]), (0.0, 0.0), 40.0, 2000, {"u": u}, ("x", "u"))
        sim = {k: v.numpy() for k, v in measure(system, rtol=1e-7, atol=1e-9).items()}
        measured = {"x": sim["x"] + noise * sim["x"].std() * rng.standard_normal(sim["x"].size), "u": sim["u"]}
        out.append(build_dataset(sim["t"], measured, DataConfig(derivatives="savgol"), spec, {"source": case},
                                 torch.float64))
    return out


@lru_cache(maxsize=None)
def report(case: str):
    train, held_out = datasets(case)
    return diagnose({"model": MODEL}, data=train, validation=held_out, options=OPTIONS)


@pytest.mark.parametrize("case", ["coulomb_and_cubic", "drag_and_cubic"])
def test_two_withheld_effects_are_both_found_in_turn(case):
    r = report(case)
    effects = r.in_turn["effects"]
    assert {e["effect"] for e in effects} == WITHHELD[case][0]  # either order
    assert [e["step"] for e in effects] == [1, 2]
    assert "--max-effects" not in r.in_turn["stopped"]  # no third effect: the loop stopped on its own
    assert r.verdict_kind is Verdict.EXPLAINED and ", then " in r.verdict
    # each effect's component is its own signal: total exponent gamma + 1. With quadratic drag
    # missing, the cubic stiffness reads 3.3 and may be accepted first at that exponent (its bootstrap
    # interval holds 3): an effect accepted early keeps the exponent it was fitted with
    tolerance = {"coulomb_and_cubic": 0.2, "drag_and_cubic": 0.35}[case]
    for e in effects:
        assert e["exponent"] + 1.0 == pytest.approx(TOTAL_EXPONENT[e["effect"]], abs=tolerance)
        # each step shrinks the held-out gap of the model before it (weak form and free run)
        assert e["heldout_rmse"]["after"] < 0.6 * e["heldout_rmse"]["before"]
        assert e["free_run_nrmse"]["after"] < e["free_run_nrmse"]["before"]
    # the second step starts from the first's adapted structure, and the final model is the second's
    assert f"**{effects[0]['exponent']:.6g}" in effects[1]["starting_equation"]
    assert all(f"**{e['exponent']:.6g}" in r.in_turn["accepted_model"]["x_ddot"] for e in effects)  # both in
    assert effects[1]["free_run_nrmse"]["after"] < 0.05
    # the final model as a module holds both effects and simulates the held-out record as closely
    held_out = datasets(case)[1]
    t, u, x = held_out.t, held_out.signals["u"], held_out.measured["x"]
    run = lambda stage: r.model(stage).simulate(t, {"u": u}, torch.tensor([float(x[0]), 0.0], dtype=torch.float64))[:, 0]
    nrmse = lambda stage: float((run(stage).detach() - x).square().mean().sqrt() / x.std())
    assert nrmse("accepted") < 0.05 < nrmse("adapted")


def test_an_offset_and_a_cubic_stiffness_are_both_found_in_turn():
    """A constant force the model lacks (an actuator offset) beside a cubic stiffness: both, in
    turn; the offset's constant is the force's, within 3 %."""
    r = report("offset_and_cubic")
    effects = r.in_turn["effects"]
    assert {e["effect"] for e in effects} == WITHHELD["offset_and_cubic"][0]
    for e in effects:
        assert e["heldout_rmse"]["after"] < 0.6 * e["heldout_rmse"]["before"]
        assert e["free_run_nrmse"]["after"] < e["free_run_nrmse"]["before"]
        if e["effect"] == "constant offset":
            assert e["exponent"] is None
        else:  # accepted first, with the offset missing: the exponent it was fitted with (as above)
            assert e["exponent"] + 1.0 == pytest.approx(3.0, abs=0.35)
    constants = re.findall(r"([+-]) ([0-9.e+-]+)(?= [+-] |$)", r.in_turn["accepted_model"]["x_ddot"])  # a bare number
    assert len(constants) == 1 and float("".join(constants[0])) == pytest.approx(0.3, rel=0.03)


def _gap(target, kind, effect=None, start="start", adapted="adapted"):
    return EquationGap(target=target, significant=kind is not Verdict.NO_GAP, verdict_kind=kind, effect=effect,
                       hypothesis="h", exponent=1.0, catalogue_exponent=None, start_equation=start,
                       retuned_equation="retuned", adapted_equation=adapted,
                       confidence={"win_frequency": 1.0}, improvement={"retuned_rmse": 1.0, "adapted_rmse": 0.5,
                                                                       "relative": 0.5},
                       structure_left=0.0, components=[], ranking=[], where={}, estimator={})


DRAG, CUBIC, BIASED = "x_dot*abs(x_dot)**1", "x*abs(x)**2", "x*abs(x)**2.3"
START_TERMS = [c["term"] for c in MODEL["equations"][0]["components"]]


def scripted(seen: list, first: Verdict = Verdict.NOT_EXPLAINED):
    """Diagnoses as a script: at the user's start the cubic stiffness is significant but not named
    (``first``: biased by the drag missing; inconclusive: not told apart from a rival); beside it,
    added provisionally, the drag is named; with the drag in, the cubic stiffness is named; with
    both, no gap. ``seen`` collects each model's terms."""
    def add(config, term):
        raw = config.model.model_dump(mode="json", exclude_none=True)
        raw["equations"][0]["components"].append({"term": term, "theta": -1.0, "adjustable": False})
        return load_config({"model": raw})

    def diagnose_round(config):
        terms = [c.term for c in config.model.equations[0].components]
        seen.append(terms)
        if terms == START_TERMS:
            kind, effect, term = first, None, BIASED
        elif DRAG not in terms:
            kind, effect, term = Verdict.EXPLAINED, "quadratic drag", DRAG
        elif CUBIC not in terms:
            kind, effect, term = Verdict.EXPLAINED, "hardening cubic stiffness", CUBIC
        else:
            kind, effect, term = Verdict.NO_GAP, None, None
        report = GapReport(kind, kind.text(effect), (_gap("x_ddot", kind, effect),), {}, {}, {}, {}, 0.0)
        return report, lambda targets: add(config, term)
    return diagnose_round


@pytest.mark.parametrize("first", [Verdict.NOT_EXPLAINED, Verdict.INCONCLUSIVE])
def test_an_effect_biased_by_another_is_accepted_once_that_one_is_in(first):
    """Both accepted in turn, the second beside a provisional power law that is taken out again
    (the first gap not explained, or inconclusive: its best fit not told apart from a rival)."""
    seen = []
    r = in_turn(load_config({"model": MODEL}), scripted(seen, first), max_effects=3)
    assert [e["effect"] for e in r.in_turn["effects"]] == ["quadratic drag", "hardening cubic stiffness"]
    assert r.in_turn["effects"][0]["beside_provisional"] == ["adapted"]
    assert r.in_turn["effects"][1]["beside_provisional"] is None
    assert r.verdict_kind is Verdict.EXPLAINED
    assert r.verdict == "gap explained by quadratic drag, then hardening cubic stiffness"
    assert r.in_turn["stopped"] == "no significant gap remains" and r.in_turn["diagnoses"] == 4
    assert seen == [START_TERMS, START_TERMS + [BIASED], START_TERMS + [DRAG],
                    START_TERMS + [DRAG, CUBIC]]  # the provisional term taken out


def test_max_effects_bounds_the_loop():
    """One effect at most: the drag, found beside the provisional term; the final model is the one
    without that term."""
    seen = []
    r = in_turn(load_config({"model": MODEL}), scripted(seen), max_effects=1)
    assert [e["effect"] for e in r.in_turn["effects"]] == ["quadratic drag"]
    assert "--max-effects" in r.in_turn["stopped"]
    assert seen[-1] == START_TERMS + [DRAG] and len(seen) == 3


DIVERGED_RETUNED = {"free_run": {"held_out": {"diverged": ["retuned"], "nrmse": {"start": 0.5, "retuned": None,
                                                                                 "adapted": 0.1},
                                               "solver": {"unconverged": [], "method": "rk4", "step": 0.01}}}}


@pytest.mark.parametrize("reason", ["checks", "free run"])
def test_no_provisional_effect_where_the_report_is_inconclusive_for_another_reason_than_a_tie(reason):
    """A tied gap beside an equation without a gap whose residual failed its checks, or with the
    re-fitted start's free run diverged, leaves the report inconclusive for another reason than
    the tie: nothing is added provisionally, the loop stops."""
    def diagnose_round(config):
        other = replace(_gap("y_ddot", Verdict.NO_GAP), verdict_kind=Verdict.INCONCLUSIVE if reason == "checks"
                        else Verdict.NO_GAP)
        gaps = (_gap("x_ddot", Verdict.INCONCLUSIVE), other)
        measures = DIVERGED_RETUNED if reason == "free run" else {}
        return GapReport(Verdict.INCONCLUSIVE, "inconclusive", gaps, measures, {}, {}, {}, 0.0), lambda targets: config
    r = in_turn(load_config({"model": MODEL}), diagnose_round, max_effects=3)
    assert r.in_turn["effects"] == [] and r.in_turn["diagnoses"] == 1
    assert r.in_turn["stopped"].startswith("no effect accepted: the diagnosis of the remaining gap is inconclusive")


def test_one_withheld_effect_stops_after_one():
    r = report("coulomb")
    assert [e["effect"] for e in r.in_turn["effects"]] == ["Coulomb friction"]
    assert r.in_turn["stopped"] == "no significant gap remains"
    assert r.verdict == "gap explained by Coulomb friction"


def test_nothing_withheld_adds_nothing():
    r = report("none")
    assert r.verdict_kind is Verdict.NO_GAP
    assert r.in_turn["effects"] == [] and r.in_turn["stopped"] == "no significant gap remains"


def test_report_files_list_the_effects(tmp_path):
    r = report("coulomb_and_cubic")
    r.save(tmp_path, plots=False)
    text = (tmp_path / "report.md").read_text()
    assert "## Effects in turn" in text and "Stopped: no significant gap remains." in text
    assert "effects in turn stopped: no significant gap remains" in str(r)


def test_an_offset_is_tried_only_where_every_signal_takes_both_signs():
    """A constant is a law of a one-signed signal (``s|s|^-1``), so the offset is not tried there,
    nor in an equation that holds a constant already."""
    equation = to_spec(load_config({"model": MODEL}).model).equations[0]
    t = torch.linspace(0, 20, 2001, dtype=torch.float64)
    signals = {"x": torch.sin(t), "x_dot": torch.cos(t), "u": torch.sin(0.7 * t)}
    assert offset_testable(equation, signals)
    assert [h.kind for h in enumerate_hypotheses(equation, offset=True)].count("offset") == 1
    assert not offset_testable(equation, {**signals, "u": 1.2 + torch.sin(0.7 * t)})  # a positive input
    assert not offset_testable(equation, {**signals, "x": torch.sin(t) + 0.97})  # 7 % of the samples below 0
    assert offset_testable(equation, {**signals, "x": torch.sin(t) + 0.9})  # 13 % below 0
    constant = load_config({"model": {**MODEL, "equations": [{**MODEL["equations"][0], "components": [
        *MODEL["equations"][0]["components"], {"term": "1", "theta": 0.1}]}]}})
    assert not offset_testable(to_spec(constant.model).equations[0], signals)


def test_adapted_structure_as_starting_model_computes_the_adapted_rate():
    spec = to_spec(load_config({"model": MODEL}).model)
    equation = spec.equations[0]
    extended = extended_equation(equation)
    hypotheses = enumerate_hypotheses(equation, offset=True)
    choices, _ = encode(equation, hypotheses)
    pick = next(c for c, h in enumerate(hypotheses) if h.kind == "additive" and h.component == 0 and h.function == 0)
    multiplicative = next(c for c, h in enumerate(hypotheses) if h.kind == "multiplicative" and h.component == 1)
    offset = next(c for c, h in enumerate(hypotheses) if h.kind == "offset")
    # slots: the two adjustable components, their copies, the constant
    cases = {pick: ([0.0, 0.0, -0.97, 0.0, 0.0], 2, 4), multiplicative: ([0.0, 0.5, 0.0, 0.0, 0.0], 2, 3),
             offset: ([0.0] * 5, 4, 4)}
    for adapted, (gamma, added, count) in cases.items():
        choice = choices[[0, 0, adapted]]  # start, retuned, adapted (the adapted model is row 2)
        g = torch.zeros(3, choice.shape[1], dtype=torch.float64)
        g[2] = torch.tensor(gamma)
        theta = torch.tensor([[-0.5, -4.0, 0.0, 0.0, 0.0]] * 3, dtype=torch.float64)
        theta[2, added] = -0.6
        scale = torch.tensor([1.7, 0.8, 1.0, 1.0], dtype=torch.float64)  # |f/s|^gamma: s folded into theta
        model = EquationModel(extended, choice, g, theta, torch.ones(3, 1, dtype=torch.float64), scale)
        components = adapted_components(equation, model)
        config = load_config({"model": {**MODEL, "equations": [{**MODEL["equations"][0], "components": components}]}})
        written = to_spec(config.model).equations[0]
        t = torch.linspace(0, 6, 301, dtype=torch.float64)
        values = {"x": torch.sin(t), "x_dot": torch.cos(1.3 * t), "u": torch.sin(0.7 * t)}
        rate = sum(float(c.theta({})) * c.term(values) for c in written.components)
        expected = model.rate({k: v.unsqueeze(0) for k, v in values.items()})[2]
        assert torch.allclose(rate, expected, rtol=1e-6, atol=1e-6)
        assert len(written.components) == count


def test_max_effects_is_checked():
    with pytest.raises(ConfigError, match="max_effects"):
        DiagnoseOptions(max_effects=0)
    assert main(["diagnose", "configs/msd_coulomb.yaml", "--max-effects", "0", "--out", "/nonexistent/x"]) == 2


def test_two_effect_zoo_cases_withhold_two_separable_effects_and_are_scored_in_any_order():
    case = generate_pair(7, samples=400)
    parts = case.truth["effects"]
    assert case.truth["kind"] == "several" and len(parts) == 2 and parts[0]["name"] != parts[1]["name"]
    assert min(p["share"] for p in parts) >= SHARE_FLOOR
    drawn = case.effect.parts
    assert separable(drawn[0].effect, drawn[1].effect)
    # the system feels both (two additive laws here): its rate is the starting model's plus both terms
    assert [p["form"] for p in parts] == ["additive", "additive"]
    frame = case.clean["train"]
    scale = case.metadata["scale"]
    values = {n: frame[n].to_numpy() / scale[n] for n in scale}
    values.update({u: frame[f"{u}_felt"].to_numpy() / scale[u] for u in case.system.inputs})
    both, alone = case.system.state_rates(values, case.effect), case.system.state_rates(values)
    for target in both:
        assert np.allclose(both[target], alone[target] + sum(p.contribution(target, values) for p in drawn))
    steps = [{"target": p["target"], "effect": p["name"], "exponent": p["exponent"],
              "hypothesis": f"{p['component']} + {p['component']}*abs({p['function']})^gamma"} for p in reversed(parts)]
    report = {"verdict": "gap explained by ...", "equations": [], "in_turn": {"effects": steps}}
    assert score.score(report, case.truth)["all_found"] and score.score(report, case.truth)["spurious"] == 0
    wrong = [{**steps[0], "exponent": steps[0]["exponent"] + 0.5}]
    scored = score.score({**report, "in_turn": {"effects": wrong}}, case.truth)
    assert scored["found"] == 0 and scored["spurious"] == 1


def test_an_explained_gap_without_catalogue_details_prints():
    """A diagnosis by simulation names its effect without the catalogue's details (``naming`` None,
    as for the cascaded tanks' hand-made config): the summary prints the verdict and the models
    (the line giving the model at the catalogue exponent raised AttributeError)."""
    gap = replace(_gap("h2_dot", Verdict.EXPLAINED, "Torricelli outflow"), where={"flagged_fraction": 0.0},
                  confidence={"win_frequency": 1.0, "bootstrap_trials": 0})
    assert gap.naming is None
    report = GapReport(Verdict.EXPLAINED, Verdict.EXPLAINED.text("Torricelli outflow"), (gap,), {}, {}, {}, {}, 0.0)
    printed = str(report)
    assert printed.startswith("verdict: gap explained by Torricelli outflow") and "  adapted:  adapted" in printed
    assert "at the catalogue exponent" not in printed
