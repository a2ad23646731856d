"""The CI slice of the withheld-effect zoo (msam_torch.zoo): generator properties with numbers on
a few cases per domain, and the diagnosis on two development-seed cases (what holds today)."""
from collections import Counter

import numpy as np
import pytest

from msam_torch.config.schema import load_config
from msam_torch.diagnosis import Verdict, diagnose
from msam_torch.diagnosis.stages.structure import relevant
from msam_torch.model.spec import split_derivative
from msam_torch.zoo import DOMAINS, NULL_SHARE, SHARE_FLOOR, generate, plan, score, sindy
from msam_torch.zoo.simulate import rms, unabsorbed
from msam_torch.zoo.system import power, term_value

SEEDS = (0, 1)  # per domain: development seeds


@pytest.fixture(scope="module")
def cases():
    return {(domain, seed): generate(seed, (domain,)) for domain in sorted(DOMAINS) for seed in SEEDS}


def test_plan_null_share_and_every_domain_reachable():
    plans = [plan(seed) for seed in range(100)]
    kinds = Counter(kind for _, kind in plans)
    assert kinds["null"] >= 20
    assert kinds["out_of_catalogue"] >= 5 and kinds["catalogued"] >= 50
    assert {domain for domain, _ in plans} == set(DOMAINS)
    assert abs(sum(plan(seed)[1] == "null" for seed in range(2000)) / 2000 - NULL_SHARE) < 0.03


@pytest.mark.slow
def test_generated_case_keeps_its_plan_and_is_deterministic(cases):
    for (domain, seed), case in cases.items():
        assert case.metadata["domain"] == domain
        assert case.truth["kind"] == plan(seed, (domain,))[1]
    again = generate(1, ("hydraulic",))
    first = cases[("hydraulic", 1)]
    assert again.config == first.config and again.truth == first.truth
    assert np.array_equal(again.train.to_numpy(), first.train.to_numpy())
    assert np.array_equal(again.validation.to_numpy(), first.validation.to_numpy())


def test_configs_load_and_declare_quantities(cases):
    for case in cases.values():
        config = load_config(case.config)
        names = set(config.model.states) | set(config.model.inputs)
        assert set(case.metadata["quantities"]) == names
        assert set(case.train.columns) == {"t"} | set(case.metadata["measured"]) | set(config.model.inputs)
        assert len(case.train) == len(case.validation) == 2000
        # the starting model is the truth's theta off by at most 20 %, in the case's units
        for eq in case.config["model"]["equations"]:
            for component in eq["components"]:
                true = case.truth["theta"][eq["target"]][component["term"]]
                nominal = case.config["model"]["parameters"][component["theta"]]
                assert abs(nominal / true - 1) <= 0.2 + 1e-12


def test_units_scale_exactly(cases):
    """The case-unit rates of the truth equal sum theta_case M + magnitude M |f|^g on the clean
    record (theta and magnitude rescaled from SI, signals scaled by 10^k, derivatives share their
    base's unit)."""
    checked = 0
    for case in cases.values():
        truth, scale = case.truth, case.metadata["scale"]
        assert all(scale[s] == 10.0 ** k for s, k in case.metadata["unit_exponents"].items())
        if truth["kind"] == "out_of_catalogue":
            continue
        frame = case.clean["train"]
        values = {name: frame[name].to_numpy() for name in frame.columns}
        rates = case.rates(frame)
        for target, theta in truth["theta"].items():
            expected = 0.0
            enters = truth["kind"] == "catalogued" and target in truth["targets"]
            for term, value in theta.items():
                replaced = enters and truth["form"] == "multiplicative" and truth["component"] == term
                expected = expected + (0.0 if replaced else value * term_value(term, values))
            if enters:
                g, s = truth["exponent"], truth["smoothing"]
                f = term_value(truth["function"], values)
                expected = expected + truth["magnitudes"][target] * power(term_value(truth["component"], values), f, g, s)
                if "exchange" in truth:
                    e = values[truth["exchange"]]
                    expected = expected - truth["exchange_magnitude"] * power(e, e, g, s)
            assert np.allclose(rates[target], expected, rtol=1e-9, atol=1e-9 * rms(rates[target]))
            checked += 1
    assert checked >= 8


def test_truth_simulation_reproduces_the_derivative(cases):
    """Simpson's rule over the true rates gives the recorded increments of each state (median
    error <= 1e-4 of the increments' RMS; a sample interval holding a step of the input is the
    only place it may not)."""
    for case in cases.values():
        frame = case.clean["train"]
        t = frame["t"].to_numpy()
        dt = t[1] - t[0]
        for target, rate in case.rates(frame).items():
            base, order = split_derivative(target)
            x = frame[base + ("" if order == 1 else "_dot")].to_numpy()
            increment = x[2::2] - x[:-2:2]
            simpson = dt / 3 * (rate[:-2:2] + 4 * rate[1:-1:2] + rate[2::2])
            error = np.abs(simpson - increment) / rms(increment)
            assert np.median(error) < 1e-4, (case.seed, target)


def test_withheld_effect_share_above_its_floor(cases):
    """Recomputed in the case's units from the clean record: the part of the effect that re-fitting
    the starting theta cannot absorb is at least the floor of the rate, as stated in the truth."""
    effects = 0
    for case in cases.values():
        truth = case.truth
        if truth["kind"] == "null":
            assert truth["share"] == 0.0
            continue
        assert truth["share"] >= truth["share_floor"] == SHARE_FLOOR
        effects += 1
        frame = case.clean["train"]
        values = {name: frame[name].to_numpy() for name in frame.columns}
        rates = case.rates(frame)
        shares = []
        for eq in case.system.equations:
            start = sum(theta * term_value(term, values) for term, theta in truth["theta"][eq.target].items())
            shares.append(rms(unabsorbed(eq, values, rates[eq.target] - start)) / rms(rates[eq.target]))
        assert max(shares) == pytest.approx(truth["share"], rel=1e-6)
        assert max(shares) >= SHARE_FLOOR
    assert effects >= 6


def test_positive_quantities_stay_positive_and_bounded(cases):
    for case in cases.values():
        for label in ("train", "validation"):
            frame = case.clean[label]
            for x in case.system.positive:
                assert frame[x].min() > 0
            assert np.isfinite(frame.drop(columns="t").to_numpy()).all()


@pytest.mark.slow
def test_diagnosis_on_a_null_and_a_torricelli_case(tmp_path):
    """What holds today on two development cases: a noise-free null heated body is 'no significant
    gap' with theta within 3 %; a cascaded-tanks case at 5 % noise names Torricelli outflow in the
    lower tank, exponent within 0.2 of -0.5 (strict top-1)."""
    null = generate(7)
    assert null.truth["kind"] == "null" and null.metadata["noise"] == 0.0
    path = null.write(tmp_path / "null")
    report = diagnose(path, data=tmp_path / "null" / "train.csv", validation=tmp_path / "null" / "validation.csv")
    figures = score.score(report, null.truth)
    assert report.verdict_kind is Verdict.NO_GAP and figures["no_gap"] and figures["theta_ok"]
    assert figures["own_run_diverged"] is False and figures["diverged_beside_verdict"] is False

    tanks = generate(4)
    assert tanks.truth["name"] == "Torricelli outflow" and tanks.truth["targets"] == ["h2_dot"]
    path = tanks.write(tmp_path / "tanks")
    report = diagnose(path, data=tmp_path / "tanks" / "train.csv", validation=tmp_path / "tanks" / "validation.csv")
    assert score.score(report, tanks.truth)["top1"]


@pytest.mark.slow
def test_a_null_whose_residual_holds_only_irrelevant_structure_reads_no_gap(tmp_path):
    """A noise-free null DC motor (zoo seed 13593) driven through a held input: its current's
    re-fitted residual was 0.35 % of its target's RMS with linear interpolation between samples,
    the quadrature error of exact data (77 % of it predicted by nearest neighbours, too little to
    matter by the null rule); with the states' shapes between samples it is below 0.01 %, a residual
    the checks pass as negligible. Structure that no effect could remove by a relevant amount is no
    gap: removing 77 % of a residual 0.35 % of the target's RMS lowers it by 0.18 % of the target's,
    below the null rule's 0.2 %; of one 1 % of it, by 0.52 %."""
    case = generate(13593)
    assert case.truth["kind"] == "null" and case.metadata["noise"] == 0.0
    path = case.write(tmp_path)
    report = diagnose(path, data=tmp_path / "train.csv", validation=tmp_path / "validation.csv")
    current = next(g for g in report.equations if g.target == "i_dot")
    assert current.improvement["retuned_rmse"] < 1e-4 * current.improvement["target_rms"]
    assert current.checks.get("negligible") and current.checks["failed"] == [], current.checks
    assert report.verdict_kind is Verdict.NO_GAP and score.score(report, case.truth)["no_gap"]
    assert not relevant(0.77, 0.0035, 1.0, 0.05, 0.002) and relevant(0.77, 0.01, 1.0, 0.05, 0.002)


def test_sindy_baseline_scores_a_case():
    pytest.importorskip("pysindy")
    case = generate(4)
    result = sindy.run(case)
    assert set(result) == {eq["target"] for eq in case.config["model"]["equations"]}
    assert all(r["threshold"] > 0 and np.isfinite(r["heldout_rmse"]) for r in result.values())
    assert set(sindy.score(result, case.truth)) == {"top1", "no_gap", "wrong_name"}


def test_wrong_names_are_counted_on_every_kind_of_case():
    """A name that is not the truth's effect in the truth's equation is a wrong name; a case whose
    effect is named right, or that names nothing, has none."""
    def report(*gaps):
        return {"verdict": "; ".join(g[1] for g in gaps), "equations": [
            {"target": t, "verdict": v, "significant": v != "no significant gap", "effect": v[15:] or None,
             "hypothesis": "w + w*abs(w)^gamma", "exponent": 1.0} for t, v in gaps]}
    truth = {"kind": "catalogued", "name": "quadratic drag", "targets": ["w_dot"], "component": "w", "function": "w",
             "exponent": 1.0}
    assert not score.score(report(("w_dot", "gap explained by quadratic drag")), truth)["wrong_name"]
    assert score.score(report(("w_dot", "gap explained by power-law damping")), truth)["wrong_name"]
    assert score.score(report(("w_dot", "gap explained by quadratic drag"), ("i_dot", "gap explained by quadratic drag")),
                       truth)["wrong_name"]  # the right name in another equation as well
    assert not score.score(report(("w_dot", "gap not explained by a catalogued effect")), truth)["wrong_name"]
    for kind in ("null", "out_of_catalogue"):
        other = {"kind": kind, "name": None, "theta": {}}
        assert score.score(report(("w_dot", "gap explained by Coulomb friction")), other)["wrong_name"]
        assert not score.score(report(("w_dot", "no significant gap")), other)["wrong_name"]


def test_a_diverged_run_is_told_from_a_diverged_run_of_the_model_the_verdict_rests_on():
    """A named effect rests on the adapted model, "no significant gap" on the re-fitted start: a
    diverged nominal model beside a named effect is counted beside the verdict, not as its own."""
    truth = {"kind": "catalogued", "name": "quadratic drag", "targets": ["w_dot"], "component": "w", "function": "w",
             "exponent": 1.0}

    def figures(kind, verdict, nrmse):
        report = {"verdict": verdict, "verdict_kind": kind, "measures": {"free_run": {"held_out": {"nrmse": nrmse}}},
                  "equations": [{"target": "w_dot", "verdict": verdict, "significant": kind != "no_gap",
                                 "effect": None, "hypothesis": "w + w*abs(w)^gamma", "exponent": 1.0}]}
        found = score.score(report, truth)
        return found["diverged_beside_verdict"], found["own_run_diverged"]

    named = "gap explained by quadratic drag"
    assert figures("explained", named, {"start": None, "retuned": 0.4, "adapted": 0.02}) == (True, False)
    assert figures("explained", named, {"start": 0.5, "retuned": 0.4, "adapted": 12.0}) == (True, True)
    assert figures("no_gap", "no significant gap", {"start": 0.5, "retuned": None, "adapted": 0.3}) == (True, True)
    assert figures("no_gap", "no significant gap", {"start": None, "retuned": 0.3, "adapted": 0.3}) == (True, False)
    assert figures("inconclusive", "inconclusive", {"start": None, "retuned": None, "adapted": None}) == (False, False)


def test_outcome_classes_read_the_verdict_where_no_equation_is_flagged():
    """A null whose equations show no significant gap but whose verdict is inconclusive (a free-run
    check failed) is 'inconclusive', not 'no gap'; with the verdict 'no significant gap' it is
    'no gap'; a catalogued case likewise, and a flagged equation classes by its own verdict."""
    from msam_torch.zoo.score import outcome

    quiet = {"x_ddot": {"verdict": Verdict.NO_GAP.text()}}
    truth = lambda kind: {"kind": kind, "targets": ["x_ddot"], "name": "Coulomb friction"}
    row = lambda kind, verdict, equations=quiet: {"ours": {"verdict": verdict, "equations": equations, "top1": False},
                                                  "truth": truth(kind)}
    assert outcome(row("null", Verdict.NO_GAP.text())) == "no gap"
    assert outcome(row("null", Verdict.INCONCLUSIVE.text())) == "inconclusive"
    assert outcome(row("out_of_catalogue", Verdict.INCONCLUSIVE.text())) == "inconclusive"
    assert outcome(row("catalogued", Verdict.NO_GAP.text())) == "no significant gap"
    assert outcome(row("catalogued", Verdict.INCONCLUSIVE.text())) == "inconclusive"
    flagged = {"x_ddot": {"verdict": Verdict.INCONCLUSIVE.text()}}
    assert outcome(row("null", Verdict.INCONCLUSIVE.text(), flagged)) == "inconclusive"
    assert outcome(row("catalogued", Verdict.INCONCLUSIVE.text(), flagged)) == "inconclusive"
