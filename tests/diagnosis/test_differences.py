"""Effects on the difference of two signals of one quantity: a spring between two masses that
hardens with their relative displacement, and Torricelli flow between two tanks driven by the
difference of their levels. The catalogue reads ``zs - zu`` of two positions as a position and
``h1 - h2`` of two levels as a level, so the laws are named as on a single signal."""
import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp

from msam_torch.diagnosis import Verdict, diagnose


def multisine(t, amplitude, periods, seed):
    phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, len(periods))
    return amplitude * sum(np.sin(2 * np.pi * t / p + f) for p, f in zip(periods, phases)) / len(periods)


def two_masses(seed: int, noise: float = 0.005):
    """Two masses on a base, the spring between them hardening: ms zs'' = -k (zs - zu)
    - k3 (zs - zu)^3 - c (zs' - zu') + u, mu zu'' = k (zs - zu) + k3 (zs - zu)^3 + c (zs' - zu') - ku zu."""
    ms, mu, k, k3, c, ku = 2.0, 0.5, 20.0, 60.0, 1.5, 150.0
    t = np.linspace(0.0, 30.0, 3001)
    u = multisine(t, 60.0, (7.0, 3.1, 1.7, 1.1, 0.77), seed)

    def rhs(time, s):
        zs, vs, zu, vu = s
        spring = k * (zs - zu) + k3 * (zs - zu) ** 3 + c * (vs - vu)
        return [vs, (-spring + np.interp(time, t, u)) / ms, vu, (spring - ku * zu) / mu]

    x = solve_ivp(rhs, (0, 30), [0, 0, 0, 0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=0.01).y
    rng = np.random.default_rng(seed + 100)
    frame = pd.DataFrame({"t": t, "zs": x[0] + noise * x[0].std() * rng.standard_normal(t.size),
                          "zu": x[2] + noise * x[2].std() * rng.standard_normal(t.size), "u": u})
    adjustments = ["abs(zs - zu)", "abs(zs_dot - zu_dot)"]
    spring = [{"term": "zs - zu", "theta": "-k/ms"}, {"term": "zs_dot - zu_dot", "theta": "-c/ms"},
              {"term": "u", "theta": "1/ms", "adjustable": False}]
    model = {"states": ["zs", "zs_dot", "zu", "zu_dot"], "inputs": ["u"],
             "quantities": {"zs": "position", "zu": "position", "u": "force"},
             "parameters": {"ms": ms, "mu": mu, "k": k, "c": c, "ku": ku},
             "equations": [{"target": "zs_ddot", "components": spring, "adjustments": adjustments},
                           {"target": "zu_ddot", "components": [
                               {"term": "zs - zu", "theta": "k/mu"}, {"term": "zs_dot - zu_dot", "theta": "c/mu"},
                               {"term": "zu", "theta": "-ku/mu", "adjustable": False}], "adjustments": adjustments}]}
    return {"model": model, "data": {"time": "t", "columns": {"zs": "zs", "zu": "zu", "u": "u"}}}, frame


def two_tanks(seed: int, noise: float = 0.005):
    """Two tanks joined at the bottom by a pipe with Torricelli flow, the second draining linearly:
    A h1' = q - a sign(h1 - h2) sqrt(2 g |h1 - h2|), A h2' = a sign(h1 - h2) sqrt(2 g |h1 - h2|) - k h2."""
    area, a, g, k = 0.4, 0.004, 9.81, 0.03
    t = np.linspace(0.0, 900.0, 3001)
    q = 0.03 + multisine(t, 0.05, (200.0, 90.0, 41.0, 23.0), seed)

    def rhs(time, h):
        between = a * np.sign(h[0] - h[1]) * np.sqrt(2 * g * abs(h[0] - h[1]))
        return [(np.interp(time, t, q) - between) / area, (between - k * h[1]) / area]

    h = solve_ivp(rhs, (0, 900), [0.6, 0.5], t_eval=t, rtol=1e-10, atol=1e-12, max_step=0.5).y
    rng = np.random.default_rng(seed + 100)
    frame = pd.DataFrame({"t": t, "h1": h[0] + noise * h[0].std() * rng.standard_normal(t.size),
                          "h2": h[1] + noise * h[1].std() * rng.standard_normal(t.size), "q": q})
    model = {"states": ["h1", "h2"], "inputs": ["q"], "quantities": {"h1": "level", "h2": "level", "q": "flow"},
             "parameters": {"A": area, "kb": 0.05, "k": k},
             "equations": [{"target": "h1_dot", "components": [
                 {"term": "h1 - h2", "theta": "-kb/A"}, {"term": "q", "theta": "1/A", "adjustable": False}],
                 "adjustments": ["abs(h1 - h2)"]},
                 {"target": "h2_dot", "components": [
                     {"term": "h1 - h2", "theta": "kb/A"}, {"term": "h2", "theta": "-k/A", "adjustable": False}],
                  "adjustments": ["abs(h1 - h2)"]}]}
    return {"model": model, "data": {"time": "t", "columns": {"h1": "h1", "h2": "h2", "q": "q"}}}, frame


@pytest.mark.slow
@pytest.mark.parametrize("case, effect, total", [(two_masses, "hardening cubic stiffness", 3.0),
                                                  (two_tanks, "Torricelli outflow", 0.5)])
@pytest.mark.parametrize("seed", [1, 2])
def test_a_law_of_a_difference_is_named(case, effect, total, seed):
    config, frame = case(seed)
    for gap in diagnose(config, data=frame).equations:  # both bodies, both tanks
        assert gap.verdict_kind is Verdict.EXPLAINED, (gap.target, gap.verdict)
        assert gap.effect == effect
        assert gap.naming["total_exponent"] == pytest.approx(total, abs=0.2)


def test_the_catalogue_reads_a_difference_by_its_quantity():
    import ast

    from msam_torch.diagnosis.catalogue.entries import Roles

    roles = Roles({"zs": "position", "zu": "position", "v": "velocity", "T": "temperature", "Ta": "temperature",
                   "N": "population", "M": "population"}, {})
    read = lambda text: roles.of_expression(ast.parse(text, mode="eval").body)
    assert read("zs - zu") == "position"  # a relative displacement reads as a displacement
    assert read("T - Ta") == "temperature_difference"  # not a temperature: radiation's T^4 does not read it
    assert read("zs - v") is None  # two quantities
    assert read("N - M") is None  # no law of a population reads a difference
    assert read("zs + zu") is None
