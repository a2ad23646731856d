"""Where the gap lies: time windows and state-space regions where the starting model's residual
concentrates.

The starting structure is fitted robustly (iteratively reweighted least squares, Tukey's
bisquare) on the weak-form rows, so theta comes from the part of the record the starting model
describes and the residual stands out where an unmodelled effect acts. Rows whose robust residual
exceeds ``threshold`` robust standard deviations are flagged; flagged rows are merged into time
windows, and simple rules on one signal (``s > a``, ``s < a``, ``|s| > a``, ``|s| < a``) are
scored by their intersection-over-union with the flagged rows.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..step import lstsq

BISQUARE = 4.685
THRESHOLD = 3.0


@dataclass(frozen=True)
class Region:
    signal: str
    rule: str  # e.g. '|x| > 0.8'
    iou: float  # agreement with the flagged rows
    kind: str  # 'gt', 'lt', 'abs_gt', 'abs_lt'
    value: float

    def mask(self, values: torch.Tensor) -> torch.Tensor:
        v = values.abs() if self.kind.startswith("abs") else values
        return v > self.value if self.kind.endswith("gt") else v < self.value


def robust_residual(design: torch.Tensor, y: torch.Tensor, iterations: int = 20) -> torch.Tensor:
    """Residual of a bisquare IRLS fit of ``y ~ design`` (M, K), (M,) -> (M,)."""
    weights = torch.ones_like(y)
    residual = y - design @ lstsq(design, y)
    for _ in range(iterations):
        scale = 1.4826 * (residual - residual.median()).abs().median()
        if not scale > 0:
            break
        u = residual / (BISQUARE * scale)
        weights = ((1 - u**2).clamp_min(0)) ** 2
        root = weights.sqrt()
        residual = y - design @ lstsq(design * root.unsqueeze(-1), y * root)
    return residual


def flag(residual: torch.Tensor, threshold: float = THRESHOLD) -> torch.Tensor:
    scale = 1.4826 * (residual - residual.median()).abs().median()
    return (residual - residual.median()).abs() > threshold * scale.clamp_min(torch.finfo(residual.dtype).tiny)


def iou(a: torch.Tensor, b: torch.Tensor) -> float:
    union = (a | b).sum()
    return float((a & b).sum() / union) if union > 0 else 0.0


def time_windows(t: torch.Tensor, flagged: torch.Tensor, residual: torch.Tensor, gap: int = 1,
                 limit: int = 10) -> list[dict]:
    """Runs of flagged rows (merging gaps up to ``gap`` rows), largest residual energy first."""
    windows, start, last = [], None, None
    indices = torch.nonzero(flagged).flatten().tolist()
    for i in indices:
        if start is None:
            start = last = i
        elif i - last <= gap + 1:
            last = i
        else:
            windows.append((start, last))
            start = last = i
    if start is not None:
        windows.append((start, last))
    energy = (residual**2).sum().clamp_min(torch.finfo(residual.dtype).tiny)
    found = [{"start": float(t[a]), "stop": float(t[b]), "energy_share": float((residual[a:b + 1] ** 2).sum() / energy)}
             for a, b in windows]
    return sorted(found, key=lambda w: -w["energy_share"])[:limit]


def state_regions(values: dict[str, torch.Tensor], flagged: torch.Tensor, quantiles: int = 39) -> list[Region]:
    """The best one-signal rule per signal, ranked by IoU with the flagged rows."""
    regions = []
    levels = torch.linspace(0.025, 0.975, quantiles, dtype=torch.float64)
    for name, v in values.items():
        best = None
        for kind in ("gt", "lt", "abs_gt", "abs_lt"):
            base = v.abs() if kind.startswith("abs") else v
            for a in torch.quantile(base, levels.to(base.dtype)).tolist():
                region = Region(name, "", 0.0, kind, a)
                score = iou(region.mask(v), flagged)
                if best is None or score > best.iou:
                    best = Region(name, _rule(name, kind, a), score, kind, a)
        if best is not None:
            regions.append(best)
    return sorted(regions, key=lambda r: -r.iou)


def _rule(name: str, kind: str, a: float) -> str:
    shown = f"|{name}|" if kind.startswith("abs") else name
    return f"{shown} {'>' if kind.endswith('gt') else '<'} {a:.4g}"
