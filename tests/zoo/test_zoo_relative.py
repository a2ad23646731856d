"""The zoo's systems whose effects act on a difference of two states (issue 54): two bodies joined
by a spring and a damper (``x1 - x2``), two connected tanks (``h1 - h2``), a two-node RLC network
(``v1 - v2``); the out-of-catalogue cases' expected names, the oracle of what a record can tell and
the check of "no significant gap" against its own evidence. Drawn and simulated (fast); one
two-body and one connected-tank case diagnosed (slow, development seeds)."""
import numpy as np
import pytest

from msam_torch.config.schema import load_config
from msam_torch.diagnosis import Verdict, diagnose
from msam_torch.model.spec import split_derivative
from msam_torch.zoo import generate, oracle, score
from msam_torch.zoo.case import draw
from msam_torch.zoo.domains import connected_tanks, rlc_network, two_bodies
from msam_torch.zoo.one_answer import one_answer
from msam_torch.zoo.simulate import rms
from msam_torch.zoo.system import differences, factors, term_value


def test_a_difference_of_two_signals_is_one_factor():
    assert factors("x1 - x2") == [("x1", "x2")] and factors("prey*pred") == [("prey",), ("pred",)]
    values = {"x1": np.array([3.0]), "x2": np.array([1.0]), "u": np.array([2.0])}
    assert term_value("x1 - x2*u", values)[0] == 4.0 and term_value("1", values) == 1.0
    assert differences(["x1 - x2", "u", "x1_dot - x2_dot", "x1 - x2"]) == ["x1 - x2", "x1_dot - x2_dot"]


def _drawn(builder, index: int):
    """A well-posed case (400 samples, 1 % noise) of ``builder``'s ``index``-th catalogued effect."""
    for seed in range(20):
        rng = np.random.default_rng([seed, index])
        system = builder(rng)
        spec = [e for e in system.effects if e.catalogued][index]
        case = draw(rng, seed, system, (spec,), 0.01, 400)
        if case is not None:
            return case, spec
    raise AssertionError(f"no well-posed {builder.__name__} case")


@pytest.mark.parametrize("builder, effects", [(two_bodies, 3), (connected_tanks, 2), (rlc_network, 2)])
def test_effects_on_a_difference_draw_simulate_and_enter_every_equation_they_act_on(builder, effects):
    """Each catalogued effect draws a case whose truth lists every equation it enters, with its
    coefficient there the system's weight times the first's (the reaction on the second body, the
    flow into the second tank); the two signals of a difference share a unit; the config loads with
    the difference among the adjustments; Simpson's rule over the true rates gives the recorded
    increments (median error <= 1e-3 of their RMS: the drive is held on a grid eight times finer than
    the samples the rule reads, and the network's first node reads it directly; an effect missing
    from one equation, or entering it with a wrong weight, misses by its share, at least 5 %)."""
    for index in range(effects):
        case, spec = _drawn(builder, index)
        truth, exponents = case.truth, case.metadata["unit_exponents"]
        assert truth["targets"] == list(spec.targets) and truth["share"] >= truth["share_floor"]
        first = truth["magnitudes"][spec.target]
        for target in spec.targets:
            assert truth["magnitudes"][target] / first == pytest.approx(spec.weight(target), rel=1e-12)
        for pair in differences(t for e in case.system.equations for t in e.terms):
            a, b = factors(pair)[0]
            assert exponents[a] == exponents[b]
            assert all(f"abs({pair})" in e["adjustments"] for e in case.config["model"]["equations"])
        load_config(case.config)
        frame = case.clean["train"]
        dt = frame["t"].iloc[1] - frame["t"].iloc[0]
        for target, rate in case.rates(frame).items():
            base, order = split_derivative(target)
            x = frame[base + ("" if order == 1 else "_dot")].to_numpy()
            increment = x[2::2] - x[:-2:2]
            simpson = dt / 3 * (rate[:-2:2] + 4 * rate[1:-1:2] + rate[2::2])
            assert np.median(np.abs(simpson - increment)) / rms(increment) < 1e-3, (builder.__name__, target)


def _report(verdict: str, **gap) -> dict:
    return {"verdict": verdict, "options": {"relative": 0.05, "absolute": 0.002},
            "equations": [{"target": "x_ddot", "verdict": verdict, "significant": verdict != "no significant gap",
                           "effect": None, "hypothesis": "x_dot + x_dot*abs(x_dot)^gamma", "exponent": 1.0, **gap}]}


def test_an_input_threshold_case_is_answered_right_only_without_a_name_while_the_catalogue_lacks_one():
    """Saturation expects the name a threshold entry would carry; the catalogue holds none yet, so
    "not explained" and "inconclusive" are right, "no significant gap" is not, any name is wrong."""
    truth = {"kind": "out_of_catalogue", "name": "saturation", "expected_name": "saturation", "targets": ["x_ddot"]}
    assert not score.catalogued("saturation") and score.catalogued("radiation")
    right = lambda verdict: score.score(_report(verdict), truth)["answered_right"]
    assert right(Verdict.NOT_EXPLAINED.text()) and right(Verdict.INCONCLUSIVE.text())
    assert not right(Verdict.NO_GAP.text()) and not right("gap explained by Coulomb friction")
    assert score.score(_report("gap explained by Coulomb friction"), truth)["confident_wrong"]
    assert not score.score(_report("gap explained by input saturation"), truth)["confident_wrong"]


def test_no_gap_beside_its_own_evidence_is_counted():
    """"No significant gap" with failed residual checks, or with rows flagged by a relevant share on
    training and held-out rows, is counted; a negligible residual or an irrelevant share is not."""
    count = lambda **gap: score.score(_report("no significant gap", **gap), {"kind": "null", "theta": {}})[
        "no_gap_beside_evidence"]
    where = {"flagged_fraction": 0.38, "split_explained": 0.75, "held_out_explained": 0.6, "residual_rms": 0.2,
             "target_rms": 1.0}
    assert count(checks={"failed": ["autocorrelated"]}) == 1 and count(checks={"failed": []}, where=where) == 1
    assert count(checks={"failed": [], "negligible": True}, where=where) == 0
    assert count(checks={"failed": []}, where={**where, "residual_rms": 1e-4}) == 0
    assert count(checks={"failed": []}, where={**where, "flagged_fraction": 0.0}) == 0


def test_the_oracle_frees_only_the_true_structure():
    case = generate(18, ("hydraulic",))  # connected tanks, Torricelli flow between them
    truth = case.truth
    reduced = oracle.oracle_config(case.config, truth)
    for equation in reduced["model"]["equations"]:
        assert equation["target"] in truth["targets"]
        assert [c["term"] for c in equation["components"] if c["adjustable"]] == ["h1 - h2"]
        assert equation["adjustments"] == ["abs(h1 - h2)"]
    assert case.config["model"]["equations"][0]["adjustments"] != ["abs(h1 - h2)"]  # the case's own is kept


@pytest.mark.slow
@pytest.mark.parametrize("domain, seed, name", [("mechanical", 5, "cubic stiffness"),
                                                ("hydraulic", 18, "Torricelli outflow")])
def test_a_law_between_two_bodies_or_two_tanks_is_named_in_both_equations(domain, seed, name, tmp_path):
    """Zoo development cases: a cubic spring between two bodies (noise-free) and
    Torricelli flow between two tanks (1 % noise) named in both equations, exponent within the
    tolerance (strict top-1); the oracle finds the records pin the law; msam run on the same
    case adapts the same law or states the diagnosis's reading."""
    case = generate(seed, (domain,))
    assert case.truth["name"] == name and len(case.truth["targets"]) == 2
    path = case.write(tmp_path)
    report = diagnose(path, data=tmp_path / "train.csv", validation=tmp_path / "validation.csv")
    assert score.score(report, case.truth)["top1"], report.verdict
    assert oracle.identifiable(case.config, case.truth, case.train, case.validation)["identifiable"]
    assert one_answer(path, report)["agrees_or_states"]
