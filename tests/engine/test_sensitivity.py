import math

import numpy as np
import torch

from msam_torch.engine.candidates import Candidate, EquationData, columns
from msam_torch.engine.sensitivity import condition_number, parameter_sensitivities, perturbation_magnitude
from tests.helpers import equation_data

D = torch.float64


def tiny_data():
    """Two adjustable components, one fixed, two magnitude functions, N = 3."""
    m1, m2, fixed = [1.0, 2.0, 3.0], [2.0, -1.0, 1.0], [1.0, 1.0, 1.0]
    f1, f2 = [1.0, 2.0, 4.0], [3.0, 0.5, 1.0]
    log_f = torch.log(torch.tensor([f1, f2], dtype=D).T).unsqueeze(0)
    return EquationData(
        y=torch.zeros(1, 3, dtype=D), components=torch.tensor([m1, m2], dtype=D).T.unsqueeze(0),
        fixed_components=torch.tensor([fixed], dtype=D).T.unsqueeze(0), log_f=log_f,
        sign_f=torch.ones_like(log_f), scale=torch.ones(1, 2, dtype=D)), (m1, m2, f1, f2)


def test_dm_matches_a_hand_computation():
    data, (m1, m2, f1, f2) = tiny_data()
    selection = data.select(torch.tensor([[0, 1]]))
    gamma, delta = torch.zeros(1, 1, 2, dtype=D), 0.5
    dm = perturbation_magnitude(columns(selection, gamma), columns(selection, gamma + delta))[0, 0]
    denominator = sum(math.hypot(a, b) for a, b in zip(m1, m2))  # sum_k ||S_k||, adjustable components only
    dm1 = sum(abs(a * (f**delta - 1.0)) for a, f in zip(m1, f1)) / denominator
    dm2 = sum(abs(b * (f**delta - 1.0)) for b, f in zip(m2, f2)) / denominator
    assert abs(float(dm[0]) - dm1) < 1e-14 and abs(float(dm[1]) - dm2) < 1e-14


def test_dm_from_columns_equals_eq15_on_full_torch_func_jacobians():
    """The column shortcut equals Eq. 15 computed from torch.func Jacobians at Gamma and Gamma + dgamma e_i."""
    data, theta, theta_fixed, _ = equation_data("harmonic")
    gamma = torch.tensor([0.3, 1.2], dtype=D)
    dgamma = 1e-2
    module = Candidate(torch.tensor([0, 1]), theta, theta_fixed, gamma)
    s = parameter_sensitivities(module, data)[0]  # (N, Q)
    expected = []
    for i in range(2):
        shifted = Candidate(torch.tensor([0, 1]), theta, theta_fixed, gamma + dgamma * torch.eye(2, dtype=D)[i])
        s_i = parameter_sensitivities(shifted, data)[0]
        expected.append(float(torch.linalg.vector_norm(s_i - s, dim=-1).sum() / torch.linalg.vector_norm(s, dim=-1).sum()))
    selection = data.select(torch.tensor([[0, 1]]))
    dm = perturbation_magnitude(columns(selection, gamma.view(1, 1, 2)), columns(selection, gamma.view(1, 1, 2) + dgamma))
    assert torch.allclose(dm[0, 0], torch.tensor(expected, dtype=D), rtol=1e-12)


def test_torch_func_parameter_sensitivities_match_finite_differences():
    data, theta, theta_fixed, _ = equation_data("harmonic")
    module = Candidate(torch.tensor([1, 0]), theta, theta_fixed, torch.tensor([0.7, -0.4], dtype=D))
    forward = parameter_sensitivities(module, data, "forward")[0]
    reverse = parameter_sensitivities(module, data, "reverse")[0]
    h = 1e-3  # the output is linear in theta: central differences are exact up to rounding
    for i in range(2):
        up = Candidate(torch.tensor([1, 0]), theta + h * torch.eye(2, dtype=D)[i], theta_fixed, module.gamma.detach())
        down = Candidate(torch.tensor([1, 0]), theta - h * torch.eye(2, dtype=D)[i], theta_fixed, module.gamma.detach())
        fd = (up(data) - down(data))[0] / (2 * h)
        assert torch.allclose(forward[:, i], fd, rtol=1e-7, atol=1e-9)
    assert torch.allclose(forward, reverse, rtol=1e-13, atol=0)
    # ... and they are the adjusted components the batched path uses (Eq. 9)
    assert torch.allclose(forward, module.columns(data)[0], rtol=1e-13, atol=0)


def test_condition_number_matches_numpy():
    phi = torch.tensor([[[1.0, 2.0], [3.0, 4.1], [5.0, 6.0]]], dtype=D)
    assert abs(float(condition_number(phi)[0]) - np.linalg.cond(phi[0].numpy().T @ phi[0].numpy())) < 1e-6
    collinear = torch.tensor([[[1.0, 2.0], [2.0, 4.0], [3.0, 6.0]]], dtype=D)
    assert float(condition_number(collinear)[0]) > 1e12
