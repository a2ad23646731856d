"""Zoo cases withholding two effects at once, for the diagnosis of several effects in turn
(:mod:`msam_torch.diagnosis.effects.multi`).

``generate_pair(seed)`` draws a system of any domain that holds two catalogued effects a diagnosis
can tell apart (:func:`~.effects.separable`), withholds both, each sized like a single withheld
effect and each at least :data:`~.case.SHARE_FLOOR` of its equation's dynamics, and returns a
:class:`~.case.Case` whose truth lists them (``kind: 'several'``, ``effects``). Deterministic in the seed;
its random stream is its own (``[seed, 2]``), so pair seeds never repeat a single-effect case.
"""
from __future__ import annotations

from itertools import combinations

import numpy as np

from msam_torch.zoo.case import ATTEMPTS, SAMPLES, Case, draw
from msam_torch.zoo.domains import DOMAINS
from msam_torch.zoo.effects import separable
from msam_torch.zoo.system import System


def pairs(system: System) -> list:
    """The separable pairs of ``system``'s catalogued effects."""
    catalogued = [e for e in system.effects if e.catalogued]
    return [(a, b) for a, b in combinations(catalogued, 2) if separable(a, b)]


def generate_pair(seed: int, noise: float | None = None, samples: int = SAMPLES) -> Case:
    """The two-effect case of ``seed`` (``noise``: fix the noise level)."""
    rng = np.random.default_rng([seed, 2])
    builders = [b for domain in sorted(DOMAINS) for b in DOMAINS[domain]]
    for _ in range(ATTEMPTS):
        system = builders[int(rng.integers(len(builders)))](rng)
        found = pairs(system)
        if not found:
            continue
        case = draw(rng, seed, system, found[int(rng.integers(len(found)))], noise, samples)
        if case is not None:
            return case
    raise RuntimeError(f"seed {seed}: no well-posed two-effect case in {ATTEMPTS} draws")
