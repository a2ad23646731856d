"""Forward-mode tangents of the fixed-step loop (:func:`msam_torch.simulation.solver._tangents`):
the plain run of the distinct rows, segmented, with the steps' chain rule in chunks, gives the
directional derivatives that autograd gives through the sequential loop, with per-row signals,
limits, substeps and rows that share their parameters."""
import math

import pytest
import torch
import torch.autograd.forward_ad as forward_ad

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.simulation import solver
from msam_torch.simulation.equations import EquationModel, _system
from msam_torch.simulation.ode import Parameters
from tests.simulation.test_segments import MODEL

N, DT = 401, 0.05


def _problem(per_row: bool):
    """The oscillator of MODEL, four rows (the last two the same parameters), adjusted by
    |x|^gamma and |x_dot|^gamma, under a multisine (per row: one amplitude each)."""
    spec = to_spec(load_config({"model": MODEL}).model)
    theta = torch.tensor([[-0.8, -4.0, 1.0], [-1.2, -6.0, 0.7], [-0.5, -3.0, 1.3], [-0.5, -3.0, 1.3]], dtype=torch.float64)
    model, p, _ = _system(spec, [EquationModel.starting(spec.equations[0], theta)])
    p = Parameters(torch.tensor([[0.7, 1.3, 0.0]], dtype=torch.float64).expand(4, 3).contiguous(),
                   torch.tensor([[1, 0, 2]]).expand(4, 3).contiguous(), p.theta, p.theta_fixed, p.scale)
    t = torch.arange(N, dtype=torch.float64) * DT
    u = sum(torch.sin(2 * math.pi * f * t + f) for f in (0.1, 0.37, 0.9)).unsqueeze(-1)
    if per_row:
        u = u * torch.tensor([1.0, 0.8, 1.2, 1.2], dtype=torch.float64).view(4, 1, 1)
    record = solver.Record(t, u, t.new_zeros(0, N), t.new_zeros(2))
    x0 = torch.tensor([[0.3, -0.2], [0.1, 0.4], [-0.2, 0.1], [-0.2, 0.1]], dtype=torch.float64)
    return model, p, record, x0


@pytest.mark.slow
@pytest.mark.parametrize("per_row, method, substeps, limited", [(False, "rk4", 1, False), (True, "midpoint", 2, True)])
def test_forward_tangents_match_autograd_through_the_sequential_loop(monkeypatch, per_row, method, substeps, limited):
    model, p, record, x0 = _problem(per_row)
    limits = torch.tensor([[-0.25, -math.inf], [0.25, math.inf]], dtype=torch.float64) if limited else None
    directions = {"gamma": torch.randn(4, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)),
                  "theta": torch.randn(4, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)),
                  "x0": torch.randn(4, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(2))}
    directions["gamma"][3] = directions["gamma"][2] * -2.0  # rows 2 and 3 share one plain run, not their tangents
    monkeypatch.setattr(solver, "TANGENT_ELEMENTS", 40)  # one-step passes in chunks of 5 steps
    monkeypatch.setattr(solver, "SEGMENT_STEPS", 100)  # the plain run in segments
    assert solver.segments(N * substeps, x0, p, record) > 1
    run = lambda q, start: solver.simulate(model, record, q, start, method, substeps, limits)
    with forward_ad.dual_level():
        dual = forward_ad.make_dual
        q = Parameters(dual(p.gamma, directions["gamma"]), p.choice, dual(p.theta, directions["theta"]),
                       dual(p.theta_fixed, torch.zeros_like(p.theta_fixed)), dual(p.scale, torch.zeros_like(p.scale)))
        states, tangent = forward_ad.unpack_dual(run(q, dual(x0, directions["x0"])))
    weights = torch.randn(states.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    gamma, theta, start = (v.clone().requires_grad_() for v in (p.gamma, p.theta, x0))
    reference = run(Parameters(gamma, p.choice, theta, p.theta_fixed, p.scale), start)
    assert torch.allclose(states, reference.detach(), rtol=1e-9, atol=1e-12)
    # per row: the weighted sum of the tangent is the gradient of the weighted sum along the direction
    for b in range(4):
        gradient = [torch.autograd.grad((reference[b] * weights[b]).sum(), v, retain_graph=True)[0][b] for v in (gamma, theta, start)]
        expected = sum(float(g @ directions[k][b]) for g, k in zip(gradient, ("gamma", "theta", "x0")))
        assert abs(float((tangent[b] * weights[b]).sum()) - expected) <= 1e-8 * max(1.0, abs(expected))
    assert float(tangent.abs().max()) > 0.1  # the run depends on the parameters
    if limited:
        assert bool((states[..., 0] >= 0.25 - 1e-12).any())  # the limit is reached
