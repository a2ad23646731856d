import math

import torch

from msam_torch.engine.fitness import correlation, fitness, nrmse, sum_abs_error


def test_fitness_is_correlation_over_sum_of_absolute_errors():
    y = torch.tensor([1.0, 2.0, 4.0, 3.0], dtype=torch.float64)
    yhat = torch.tensor([1.5, 1.0, 4.0, 2.0], dtype=torch.float64)
    eps = [-0.5, 1.0, 0.0, 1.0]
    my, mh = sum(y.tolist()) / 4, sum(yhat.tolist()) / 4
    cov = sum((a - my) * (b - mh) for a, b in zip(y.tolist(), yhat.tolist()))
    rho = cov / math.sqrt(sum((a - my) ** 2 for a in y.tolist()) * sum((b - mh) ** 2 for b in yhat.tolist()))
    assert float(sum_abs_error(y, yhat)) == sum(abs(e) for e in eps) == 2.5
    assert abs(float(correlation(yhat, y)) - rho) < 1e-14
    assert abs(float(fitness(y, yhat)) - rho / 2.5) < 1e-14


def test_fitness_of_constant_or_non_finite_output():
    y = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    assert float(correlation(torch.ones(3, dtype=torch.float64), y)) == 0.0
    assert float(fitness(y, torch.tensor([1.0, float("nan"), 3.0], dtype=torch.float64))) == -math.inf


def test_nrmse_is_rmse_over_std():
    y = torch.tensor([0.0, 2.0, 4.0], dtype=torch.float64)
    assert abs(float(nrmse(y, y + 1.0)) - 1.0 / 2.0) < 1e-14
