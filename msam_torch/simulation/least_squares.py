"""Levenberg-Marquardt on theta and the initial states for fixed exponents: the starting model's
fit (``simulation.prefit_steps``), the refit before every exponent step (``refit_steps``) and the
initial states of free runs. The Jacobians are exact (:mod:`.sensitivities`)."""
from __future__ import annotations

import torch

from msam_torch.engine.step import lstsq
from msam_torch.simulation.problem import SimulationData, unpacked, usable
from msam_torch.simulation.sensitivities import jacobians

DAMPING = (0.0, 1e-4, 1e-2, 1.0)  # Levenberg-Marquardt dampings tried at once


def fit_parameters(data: SimulationData, choice, gamma, z, free: torch.Tensor, steps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Levenberg-Marquardt on the ``free`` entries of z (T, C, Z) for fixed exponents (T, C, Qa).

    Each step tries the dampings of :data:`DAMPING` together with their Jacobians in one batched
    simulation and keeps, per candidate, the best that lowers the sum of squares; the steps end
    early when no candidate improves (every later step would repeat that one). Returns z and the
    simulated output (T, C, M).
    """
    q = gamma.shape[-1]
    p = z.shape[-1] - q - data.initial.shape[-1]
    if steps == 0 or not bool(free.any()):
        return z, data.output(gamma, choice, *unpacked(z, q, p))
    y = data.y.unsqueeze(1)
    n = len(DAMPING)

    def linearise(points):  # (T, C, L, Z) -> output (T, C, L, M), Jacobian (T, C, L, M, Zf)
        g = gamma.unsqueeze(-2).expand(points.shape[:-1] + (q,))
        c = choice.unsqueeze(-2).expand(points.shape[:-1] + (q,))
        jac = jacobians(data, c.flatten(1, 2), g.flatten(1, 2), points.flatten(1, 2), 1.0, free, structural=False)
        return jac.base.unflatten(1, points.shape[1:3]), jac.z[..., free].unflatten(1, points.shape[1:3])

    out, jz = (v.squeeze(2) for v in linearise(z.unsqueeze(-2)))
    sse = torch.where(usable(out), (y - out) ** 2, torch.inf).sum(-1)
    for _ in range(steps):
        eps = torch.where(usable(out), y - out, torch.zeros_like(out))
        deltas = torch.stack([lstsq(jz, eps, damping) for damping in DAMPING], -2)  # (T, C, L, Zf)
        trial = z.unsqueeze(-2).repeat_interleave(n, -2)
        trial[..., free] = trial[..., free] + deltas
        out_t, jz_t = linearise(trial)
        sse_t = torch.where(usable(out_t), (y.unsqueeze(-2) - out_t) ** 2, torch.inf).sum(-1)  # (T, C, L)
        best_sse, best = sse_t.min(-1)
        better = best_sse < sse
        if not bool(better.any()):  # every later step would repeat this one: none improves
            break
        pick = lambda v: v.gather(2, best.view(best.shape + (1,) * (v.dim() - 2)).expand(v.shape[:2] + (1,) + v.shape[3:])).squeeze(2)
        keep = lambda new, old: torch.where(better.view(better.shape + (1,) * (old.dim() - 2)), new, old)
        z, out, jz, sse = keep(pick(trial), z), keep(pick(out_t), out), keep(pick(jz_t), jz), torch.where(better, best_sse, sse)
    return z, out
