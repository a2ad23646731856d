"""What simulation-based evaluation works on: the model, the training record, the solver options
and the starting point, and the simulated outputs of any batch of candidates.

Least-squares parameters ``z = [theta, theta_fixed, initial]`` (Z = Qa + P + S) are packed
per candidate. Shapes: ``T`` trials, ``C`` candidates, ``N`` samples, ``O`` outputs, ``S``
simulated states, ``Qa`` adjustable and ``P`` fixed components, ``G`` adjustment functions.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch

from msam_torch.engine.values import State
from msam_torch.simulation.grids import Grids
from msam_torch.simulation.ode import Parameters, SystemModel
from msam_torch.simulation.record import Record
from msam_torch.simulation.solver import simulate


@dataclass(frozen=True)
class SimulationData:
    """The model, the training record, solver options and the parameters of the starting point
    (theta are the trainer's; ``initial`` (T, S) and ``scale`` (T, G) are the simulation's own)."""

    model: SystemModel
    record: Record
    outputs: tuple[int, ...]  # indices of the output states
    initial: torch.Tensor  # (T, S)
    scale: torch.Tensor  # (T, G)
    free: torch.Tensor  # (Z,) bool: which of theta, theta_fixed, initial are estimated
    method: str = "rk4"
    substeps: int = 1
    refit_steps: int = 0  # Levenberg-Marquardt steps on theta and initial states before every exponent step
    limits: torch.Tensor | None = None  # (2, S) range of the simulated states (``simulation.saturation``)
    grids: Grids = field(default_factory=Grids, compare=False, repr=False)  # rows already integrated (:mod:`.grids`)

    @property
    def y(self) -> torch.Tensor:
        """Measured outputs, flattened (1, O N)."""
        return self.record.outputs.reshape(1, -1)

    def select(self, choices: torch.Tensor) -> "SimulationSelection":
        return SimulationSelection(self, choices)

    def output(self, gamma, choice, theta, theta_fixed, initial, probe: float = 0.0) -> torch.Tensor:
        """Simulated outputs for any leading batch shape (T, ...): (T, ..., O N). With ``probe``,
        the rows at ``gamma + probe e_i`` (Eq. 16's shifted exponents) are integrated in the same
        batch and kept in :attr:`grids`, where a step from these points reads its plain runs."""
        batch = gamma.shape[:-1]
        if probe:
            q = gamma.shape[-1]
            shifted = gamma.unsqueeze(-2) + probe * torch.eye(q, dtype=gamma.dtype, device=gamma.device)  # (..., Qa, Qa)
            along = lambda v: v.expand(batch + v.shape[-1:]).unsqueeze(-2).expand(batch + (q + 1,) + v.shape[-1:])
            rows = [along(v) for v in (choice, theta, theta_fixed, initial)]
            return self.output(torch.cat([gamma.unsqueeze(-2), shifted], -2), *rows)[..., 0, :]
        flat = lambda v: v.expand(batch + v.shape[-1:]).flatten(0, len(batch) - 1)
        t = self.scale.shape[0]
        scale = self.scale.view((t,) + (1,) * (len(batch) - 1) + self.scale.shape[-1:]) if len(batch) > 1 else self.scale
        p = Parameters(flat(gamma), flat(choice), flat(theta), flat(theta_fixed), flat(scale))
        states = simulate(self.model, self.record, p, flat(initial), self.method, self.substeps, self.limits,
                          grids=self.grids)
        if self.limits is not None:  # a fixed step may overshoot a limit by a fraction of a step
            states = torch.clamp(states, self.limits[0], self.limits[1])
        out = states[..., list(self.outputs)].movedim(-1, -2).reshape(states.shape[0], -1)
        return out.reshape(batch + out.shape[-1:])


@dataclass(frozen=True)
class SimulationSelection:
    data: SimulationData
    choices: torch.Tensor  # (C, Qa) or (T, C, Qa)

    @property
    def y(self) -> torch.Tensor:
        return self.data.y.unsqueeze(1)  # (1, 1, O N)

    def choice(self, state: State) -> torch.Tensor:
        return self.choices.expand(state.gamma.shape)


def packed(state: State, initial: torch.Tensor) -> torch.Tensor:
    """The least-squares parameters z = [theta, theta_fixed, initial] (..., Z)."""
    return torch.cat([state.theta, state.theta_fixed, initial], -1)


def unpacked(z: torch.Tensor, q: int, p: int):
    """theta, theta_fixed and initial states from z."""
    return z[..., :q], z[..., q: q + p], z[..., q + p:]


def usable(values: torch.Tensor) -> torch.Tensor:
    """Finite and far from overflow (squares and sums of it stay finite)."""
    return torch.isfinite(values) & (values.abs() < 1e100)
