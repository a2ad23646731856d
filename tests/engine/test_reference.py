"""The batched engine against the sequential reference path (one Candidate module at a time,
sensitivities by torch.func)."""
import pytest
import torch

from msam_torch.data.systems import perturb_parameters
from msam_torch.engine.candidates import Candidate, Selection, enumerate_choices
from msam_torch.engine.reference import reference_round_robin, reference_step
from msam_torch.engine.step import evaluate, step
from msam_torch.engine.trainer import Trainer
from msam_torch.engine.values import State, StepOptions
from tests.helpers import equation_data

D = torch.float64
OPTIONS = [StepOptions(), StepOptions(scaling="gauss_newton", step_size="one", theta="varpro"),
           StepOptions(step_size="line_search", theta="varpro"), StepOptions(scaling="gauss_newton", damping=1e-3)]


@pytest.mark.parametrize("name", ["harmonic", "sode3"])
@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: f"{o.scaling}-{o.step_size}-{o.theta}-{o.damping}")
def test_batched_step_equals_the_reference_step(name, options):
    data, theta, theta_fixed, _ = equation_data(name, normalize="rms" if options.theta == "varpro" else "none")
    choices = enumerate_choices(data.log_f.shape[-1], theta.shape[0])[:6]
    c, q = choices.shape
    gamma = 0.5 * torch.randn(1, c, q, dtype=D)
    selection = data.select(choices)
    state = State(gamma, theta.expand(1, c, q), theta_fixed.expand(1, c, theta_fixed.shape[0]), torch.zeros(1, c, dtype=torch.bool))
    batched = step(selection, state, evaluate(selection, state, options), options)
    for k in range(c):
        ref = reference_step(Candidate(choices[k], theta, theta_fixed, gamma[0, k]), data, options)
        assert torch.allclose(batched.dm[0, k], ref.dm, rtol=1e-10, atol=0)
        assert abs(float(batched.mu[0, k]) - ref.mu) < 1e-8
        scale = float(ref.delta.abs().max())
        assert torch.allclose(batched.state.gamma[0, k], ref.gamma, rtol=0, atol=1e-8 * max(1.0, scale)), (k, batched.state.gamma[0, k], ref.gamma)


def test_round_robin_winner_and_exponents_match_the_reference_path():
    data, theta, theta_fixed, spec_eq = equation_data("harmonic")
    parameters = perturb_parameters({"m": 375.0, "c": 9800.0, "k": 130000.0}, 0.5, torch.Generator().manual_seed(1))
    theta = torch.tensor([-parameters["c"] / parameters["m"], -parameters["k"] / parameters["m"]], dtype=D)
    theta_fixed = torch.tensor([1 / parameters["m"]], dtype=D)
    options = StepOptions()
    choices = enumerate_choices(2, 2)
    fitness, gamma = reference_round_robin(data, choices, theta, theta_fixed, options, 15)
    fit = Trainer(options, 15, 0).fit(data, theta.unsqueeze(0), theta_fixed.unsqueeze(0), choices=choices)
    assert int(fit.winner[0]) == int(fitness.argmax())
    assert torch.allclose(fit.ranking_fitness[0], fitness, rtol=1e-9)
    assert torch.allclose(fit.ranking_gamma[0], gamma, rtol=0, atol=1e-9)


@pytest.mark.slow
def test_line_search_round_robin_matches_the_reference_path(monkeypatch):
    """The batched line search skips settled candidates and evaluates the still-open ones as a
    batch of their own; neither may change a result of the one-candidate-at-a-time reference."""
    data, _, _, _ = equation_data("harmonic", normalize="rms")
    parameters = perturb_parameters({"m": 375.0, "c": 9800.0, "k": 130000.0}, 1.0, torch.Generator().manual_seed(2))
    theta = torch.tensor([-parameters["c"] / parameters["m"], -parameters["k"] / parameters["m"]], dtype=D)
    theta_fixed = torch.tensor([1 / parameters["m"]], dtype=D)
    options = StepOptions(scaling="gauss_newton", step_size="line_search", theta="varpro")
    choices = enumerate_choices(2, 2)
    taken = []
    original_take = Selection.take
    monkeypatch.setattr(Selection, "take", lambda self, *a: taken.append(len(a[0])) or original_take(self, *a))
    fit = Trainer(options, 15, 0).fit(data, theta.unsqueeze(0), theta_fixed.unsqueeze(0), choices=choices)
    fitness, gamma = reference_round_robin(data, choices, theta, theta_fixed, options, 15)
    assert taken and max(taken) <= choices.shape[0] // 2  # the open-candidate batches were used
    assert int(fit.winner[0]) == int(fitness.argmax())
    exact = fitness > 1e9  # the true structure fits to rounding: its fitness is 1 / (rounding error)
    assert int(exact.sum()) == 1 and bool(fit.ranking_fitness[0][exact] > 1e9)
    assert torch.allclose(fit.ranking_fitness[0][~exact], fitness[~exact], rtol=1e-9)
    assert torch.allclose(fit.ranking_gamma[0], gamma, rtol=0, atol=1e-8)
