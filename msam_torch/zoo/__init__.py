"""A generated zoo of withheld-effect cases across physical domains (issue: a diagnosis that
holds on systems nobody tuned it to).

``generate(seed)`` draws a first-principles system, random parameters, units, excitation,
measured subset and noise, withholds one effect of its domain's catalogue, an out-of-catalogue
effect, or nothing, and returns a :class:`Case` with its truth, its starting-model config in the
project's schema and its training and held-out records; ``generate_pair(seed)`` withholds two
effects at once (:mod:`.pairs`).
"""
from msam_torch.zoo import score, sindy
from msam_torch.zoo.case import NOISE_LEVELS, NULL_SHARE, SHARE_FLOOR, Case, generate, plan
from msam_torch.zoo.domains import DOMAINS
from msam_torch.zoo.effects import OUT_OF_CATALOGUE
from msam_torch.zoo.pairs import generate_pair

__all__ = ["score", "sindy", "generate", "generate_pair", "plan", "NULL_SHARE", "Case", "DOMAINS", "OUT_OF_CATALOGUE", "NOISE_LEVELS", "SHARE_FLOOR"]
