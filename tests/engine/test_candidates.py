import torch

from msam_torch.engine.candidates import Candidate, columns, enumerate_choices, evaluate_stacked, predict
from tests.helpers import equation_data

D = torch.float64


def test_enumeration_covers_every_assignment():
    choices = enumerate_choices(3, 3)
    assert choices.shape == (27, 3)
    assert len({tuple(c) for c in choices.tolist()}) == 27


def test_batched_candidates_equal_one_by_one_modules():
    data, theta, theta_fixed, _ = equation_data("vanderpol")
    choices = enumerate_choices(2, 3)
    gamma = torch.randn(1, choices.shape[0], 3, dtype=D)
    selection = data.select(choices)
    batched = predict(selection, columns(selection, gamma), theta.expand(1, 8, 3), theta_fixed.expand(1, 8, 0))
    modules = [Candidate(c, theta, theta_fixed, g) for c, g in zip(choices, gamma[0])]
    stacked = evaluate_stacked(modules, data)  # torch.func: stack_module_state + vmap + functional_call
    for c, module in enumerate(modules):
        one = module(data)[0]
        assert torch.allclose(batched[0, c], one, rtol=1e-13, atol=1e-12)
        assert torch.allclose(stacked[c, 0], one, rtol=1e-13, atol=1e-12)


def test_signed_adjustment_keeps_the_sign_and_zero_is_guarded():
    data, theta, theta_fixed, eq = equation_data("sode3")
    module = Candidate(torch.tensor([2, 2, 2]), theta, theta_fixed, torch.tensor([1.0, 1.0, -3.0], dtype=D))
    x3 = data.log_f[0, :, 2].exp() * data.sign_f[0, :, 2]
    cols = module.columns(data)[0]
    assert torch.allclose(cols[:, 0], data.components[0, :, 0] * x3, rtol=1e-12)
    assert torch.isfinite(cols).all()  # negative exponent of a function that crosses zero


def test_projected_columns_project_only_the_varying_ones_with_the_same_values():
    """A projected selection (weak form) evaluates and projects only the columns whose |f| varies
    along the samples; the others are their projected component times |f|^gamma. Same values as
    projecting every column, with and without row weights, for gamma with an extra leading axis."""
    from msam_torch.engine.candidates import Selection, power
    from msam_torch.engine.weak_form import Projection, TestFunctions

    torch.manual_seed(0)
    t, c, n, q = 3, 5, 400, 4
    tests = TestFunctions.build(torch.arange(n, dtype=torch.float64) * 0.01, 6)
    log_f = torch.randn(t, c, q, n, dtype=torch.float64)
    log_f[:, :, 1] = 0.0  # the function 1
    log_f[:, 2, 3] = -27.6  # a constant level (the floor: the function 0)
    log_f = log_f.mT  # (T, C, N, Q), stored sample-axis last as Selection keeps it
    signed = torch.randn(t, c, q, n, dtype=torch.float64).mT
    for root in (None, torch.rand(t, tests.count(n), dtype=torch.float64)):
        projection = Projection(tests, root)
        selection = Selection(torch.zeros(t, 1, n, dtype=torch.float64), signed, log_f,
                              torch.zeros(t, 1, n, 0, dtype=torch.float64), projection)
        varying = torch.zeros(c, q, dtype=torch.bool)
        varying[selection.levels()[0]] = True
        assert int(varying.sum()) == c * q - c - 1 and not bool(varying[:, 1].any()) and not bool(varying[2, 3])
        for gamma in (torch.randn(t, c, q, dtype=torch.float64), torch.randn(2, t, c, q, dtype=torch.float64)):
            whole = projection(signed * power(log_f, gamma.unsqueeze(-2)))
            got = columns(selection, gamma)
            assert got.shape == whole.shape
            assert torch.allclose(got, whole, rtol=1e-12, atol=1e-14 * float(whole.abs().max()))
