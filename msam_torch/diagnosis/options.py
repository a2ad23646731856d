"""Options of :func:`msam_torch.diagnosis.diagnose` (the defaults are the documented method)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from msam_torch.errors import ConfigError
from msam_torch.run.estimation import SAMPLES

AGREEMENT = 1e-2  # free runs at a step and at twice it agree within this share of a state's magnitude:
# the resolution to which the diagnosis checks its free runs, and so compares them


@dataclass(frozen=True)
class DiagnoseOptions:
    """Options of :func:`msam_torch.diagnosis.diagnose` (defaults are the documented method)."""

    half_width: float | None = None  # test-function half-width in time units (default: from the band, msam_torch.run.estimation)
    steps: int = 30  # damped variable-projection steps per hypothesis
    damping: float = 1e-3  # Levenberg-Marquardt damping of the exponent steps
    bootstrap: int = 16  # bootstrap trials (time blocks and noise), run as one batch
    bootstrap_steps: int = 8  # steps per bootstrap trial, warm-started at the original fit
    bootstrap_hypotheses: int = 5  # the best effect hypotheses (and the re-fitted start) re-fitted per trial
    quadrature_samples: int = SAMPLES  # records are low-pass filtered and decimated to about this many samples
    blocks: int = 10  # time blocks for the bootstrap and, without held-out data, the held-out split
    relative: float = 0.05  # null rule: held-out RMSE at least 5 % below the re-fitted starting model
    absolute: float = 0.002  # ... and by 0.2 % of the held-out target's RMS
    min_win_frequency: float = 0.5  # bootstrap share the named effect must win
    apart_level: float = 0.05  # ... and the p-value that another name predicts the held-out data as well, at most
    max_structure_left: float = 0.25  # residual structure the effect may leave (share of the gap's)
    check_level: float = 0.01  # "no significant gap": p-values of the residual's whiteness checks at least this
    max_residual_structure: float = 0.2  # ... and nearest neighbours predict at most this share of its mean square
    free_run: bool = True  # simulate the models (torchdiffeq)
    solver: str = "rk4"  # torchdiffeq method of the free-run simulations
    solver_step: float | None = None  # fixed-step solvers: step in time units (default: halved until converged)
    rtol: float = 1e-6  # adaptive solvers: relative tolerance
    atol: float = 1e-8  # adaptive solvers: absolute tolerance, relative to each state's measured magnitude
    seed: int = 0
    max_effects: int = 1  # effects added in turn, at most (.multi; 1: the first effect only, no loop)

    def __post_init__(self):
        """Every option in its range, else a :class:`~msam_torch.errors.ConfigError` naming it."""
        for name, least in WHOLE.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ConfigError(name, f"expected a whole number of at least {least}, got {value!r}")
        for name, (low, high, above, none) in BOUNDED.items():
            value = getattr(self, name)
            if value is None and none:
                continue
            number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if not number or value < low or (above and value == low) or (high is not None and value > high):
                wanted = ("a positive number" if above else f"a number of at least {low:g}") if high is None \
                    else f"a number in [{low:g}, {high:g}]"
                raise ConfigError(name, f"expected {wanted}{' or None' if none else ''}, got {value!r}")


WHOLE = {"steps": 1, "bootstrap": 0, "bootstrap_steps": 1, "bootstrap_hypotheses": 1, "quadrature_samples": 1,
         "blocks": 2, "max_effects": 1}  # whole-number options and their least values
# option: (least value, greatest or None, above the least only, None allowed); shares lie in [0, 1]
BOUNDED = {"half_width": (0.0, None, True, True), "solver_step": (0.0, None, True, True),
           "rtol": (0.0, None, True, False), "atol": (0.0, None, True, False),
           "damping": (0.0, None, False, False), "absolute": (0.0, None, False, False),
           **{share: (0.0, 1.0, False, False) for share in ("relative", "min_win_frequency", "apart_level",
                                                            "max_structure_left", "check_level",
                                                            "max_residual_structure")}}
