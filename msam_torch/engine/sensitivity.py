"""Sensitivities: parameter sensitivities, model perturbation magnitude dM (Eq. 14-15),
structural sensitivities (Eq. 16) and the condition number of ``Phi^T Phi`` (Figure 5).

For the model class of Eq. 9 the parameter sensitivity ``d yhat / d theta_i`` is the adjusted
component ``M_i f_i^gamma_i`` and moving ``gamma_i`` changes only that column, so the batched
functions below take the columns at ``Gamma`` and at ``Gamma + dgamma`` (column ``i`` perturbed
in ``gamma_i`` alone). :func:`parameter_sensitivities` computes the same quantity generically with
``torch.func`` for any candidate module; the tests check the two against each other.
"""
from __future__ import annotations

import torch
from torch import nn


def parameter_sensitivities(module: nn.Module, data, mode: str = "forward") -> torch.Tensor:
    """``d yhat / d theta`` of ``module`` by torch.func (``jacfwd`` or ``jacrev``): (..., N, Q)."""
    from torch.func import functional_call, jacfwd, jacrev

    params = {k: v.detach() for k, v in module.named_parameters()}
    buffers = {k: v for k, v in module.named_buffers() if k != "theta"}

    def output(theta):
        return functional_call(module, (params, {**buffers, "theta": theta}), (data,))

    jacobian = jacfwd if mode == "forward" else jacrev
    return jacobian(output)(module.theta)


def perturbation_magnitude(cols: torch.Tensor, cols_perturbed: torch.Tensor) -> torch.Tensor:
    """Eq. 15: ``dM_i = sum_k |S_ki(Gamma + dgamma e_i) - S_ki| / sum_k ||S_k||_2``.

    ``S`` is the sensitivity to the adjustable components' theta (design decision: the fixed
    components are left out of the denominator). Shapes (..., N, Q) -> (..., Q).
    """
    return perturbation_magnitude_from_change(cols, cols_perturbed - cols)


def perturbation_magnitude_from_change(cols: torch.Tensor, change: torch.Tensor) -> torch.Tensor:
    """Eq. 15 from the columns and their change ``S(Gamma + dgamma e_i) - S`` (column i alone)."""
    numerator = torch.linalg.vector_norm(change, 1, dim=-2)  # sum_t |change|, one pass
    squares = cols.new_zeros(cols.shape[:-1])  # ||S(t)||^2 accumulated column by column: no (..., N, Q) temporary
    for column in cols.unbind(-1):
        squares.addcmul_(column, column)
    denominator = squares.sqrt_().sum(-1, keepdim=True)
    return numerator / denominator.clamp_min(torch.finfo(cols.dtype).tiny)


def structural_sensitivities(delta_yhat: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
    """Eq. 16: ``Phi_i = [yhat(Gamma + dgamma e_i) - yhat(Gamma)] / step_i``.

    ``step`` is ``dM_i`` (dM-scaled) or ``dgamma`` (plain finite difference). (..., N, Q).
    """
    return delta_yhat / step.unsqueeze(-2).clamp_min(torch.finfo(delta_yhat.dtype).tiny)


def condition_number(phi: torch.Tensor) -> torch.Tensor:
    """``lambda_max / lambda_min`` of ``Phi^T Phi`` (inf where singular): (...,)."""
    return gram_condition_number(phi.mT @ phi)


def safe_eigh(matrix: torch.Tensor):
    """``torch.linalg.eigh`` of a batch in which some matrices may hold inf or nan (a diverging
    candidate): those are replaced by the identity so the rest of the batch is unaffected.
    Returns eigenvalues, eigenvectors and the mask of finite matrices."""
    finite = torch.isfinite(matrix).all(-1).all(-1)
    eye = torch.eye(matrix.shape[-1], dtype=matrix.dtype, device=matrix.device)
    values, vectors = torch.linalg.eigh(torch.where(finite[..., None, None], matrix, eye))
    return values, vectors, finite


def gram_condition_number(gram: torch.Tensor) -> torch.Tensor:
    """``lambda_max / lambda_min`` of a Gram matrix ``Phi^T Phi`` (inf where singular or not
    finite): (...,)."""
    eigenvalues, _, finite = safe_eigh(gram)
    smallest = eigenvalues[..., 0].clamp_min(0)
    ratio = eigenvalues[..., -1] / smallest
    return torch.where((smallest > 0) & finite, ratio, torch.full_like(ratio, torch.inf))
