"""Where the gap lies: the state-space region and time windows where the starting model fails.

1. Split: for every one-signal rule ``R`` (``s > a``, ``s < a``, ``|s| > a``, ``|s| < a``, ``a`` on
   a grid of quantiles) the starting structure (theta free) is fitted separately inside and outside
   ``R`` on the one-step rows (estimated derivative), all rules as one batch; the rule whose two-regime fit removes the
   most squared residual is where the model changes behaviour. Its side with the smaller residual
   is where the starting model holds; concentration steps (as in least trimmed squares) fit the
   starting structure to the better-fitting half of that side.
2. Flag: the starting structure fitted on that side alone predicts every row; rows whose residual
   exceeds ``THRESHOLD`` robust standard deviations of that side's residual are flagged, and the fit
   is repeated on the unflagged rows until the flagged set settles (when the
   split removes at least ``MIN_EXPLAINED`` of the single-fit residual) and merged into time
   windows; the one-signal rule that best matches the flagged rows (intersection over union)
   describes the region.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from ..step import lstsq

MIN_EXPLAINED = 0.2
THRESHOLD = 3.0
ITERATIONS = 10
MIN_SHARE = 0.1  # each regime holds at least this share of the rows


@dataclass(frozen=True)
class Region:
    signal: str
    rule: str  # e.g. '|x| > 0.8'
    kind: str  # 'gt', 'lt', 'abs_gt', 'abs_lt'
    value: float
    share: float  # fraction of the rows inside
    explained: float  # intersection over union with the flagged rows

    def mask(self, values: torch.Tensor) -> torch.Tensor:
        v = values.abs() if self.kind.startswith("abs") else values
        return v > self.value if self.kind.endswith("gt") else v < self.value


def _sse(design: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted least-squares residual sum of squares for every row of ``weights`` (R, M) -> (R,)."""
    root = weights.sqrt()
    x = lstsq(design * root.unsqueeze(-1), y * root)
    return (weights * (y - (design @ x.unsqueeze(-1)).squeeze(-1)) ** 2).sum(-1)


def _candidates(values: dict[str, torch.Tensor], quantiles: int, dtype) -> list[Region]:
    levels = torch.linspace(0.025, 0.975, quantiles, dtype=dtype)
    rules = []
    for name, v in values.items():
        for kind in ("gt", "lt", "abs_gt", "abs_lt"):
            base = v.abs() if kind.startswith("abs") else v
            for a in torch.quantile(base, levels).tolist():
                region = Region(name, _rule(name, kind, a), kind, a, 0.0, 0.0)
                rules.append(replace(region, share=float(region.mask(v).double().mean())))
    return rules


def localise(design: torch.Tensor, y: torch.Tensor, values: dict[str, torch.Tensor], quantiles: int = 39):
    """``(regions, flagged, residual, explained)``: the best rule per signal by its intersection
    over union with the flagged rows (M,), the residual of the fit where the model holds, and the
    squared residual the best split removes."""
    tiny = torch.finfo(y.dtype).tiny
    total = _sse(design, y, torch.ones_like(y).unsqueeze(0))[0].clamp_min(tiny)
    rules = [r for r in _candidates(values, quantiles, y.dtype) if MIN_SHARE <= r.share <= 1 - MIN_SHARE]
    if not rules:
        return [], torch.zeros_like(y, dtype=torch.bool), y - design @ lstsq(design, y), 0.0
    inside = torch.stack([r.mask(values[r.signal]) for r in rules]).to(y.dtype)
    sse_in, sse_out = _sse(design, y, inside), _sse(design, y, 1 - inside)
    explained = 1 - (sse_in + sse_out) / total
    best = int(explained.argmax())
    rows_in = inside[best].sum().clamp_min(1)
    side = inside[best] if sse_in[best] / rows_in <= sse_out[best] / (len(y) - rows_in).clamp_min(1) else 1 - inside[best]
    fit = lambda weights: y - design @ lstsq(design * weights.sqrt().unsqueeze(-1), y * weights.sqrt())
    core = side
    for _ in range(ITERATIONS):  # concentration steps: re-fit on the better-fitting half of that side
        magnitude = fit(core).abs()
        core = side * (magnitude <= magnitude[side > 0].median()).to(y.dtype)
    holds = side
    for _ in range(ITERATIONS):  # flag against that fit, re-fit on the rows that still hold, until settled
        residual = fit(core)
        held = residual[holds > 0]
        scale = 1.4826 * (held - held.median()).abs().median()
        flagged = (residual - held.median()).abs() > THRESHOLD * scale.clamp_min(tiny)
        if (~flagged).double().mean() < MIN_SHARE or torch.equal(~flagged, holds > 0):
            break
        holds = core = (~flagged).to(y.dtype)
    if float(explained[best]) < MIN_EXPLAINED:
        flagged = torch.zeros_like(flagged)
    regions = {}
    for r in _candidates(values, quantiles, y.dtype):
        score = iou(r.mask(values[r.signal]), flagged)
        if r.signal not in regions or score > regions[r.signal].explained:
            regions[r.signal] = replace(r, explained=score)
    ranked = sorted(regions.values(), key=lambda r: -r.explained)
    return ranked, flagged, residual, float(explained[best])


def iou(a: torch.Tensor, b: torch.Tensor) -> float:
    union = (a | b).sum()
    return float((a & b).sum() / union) if union > 0 else 0.0


def time_windows(t: torch.Tensor, flagged: torch.Tensor, residual: torch.Tensor, gap: int = 5,
                 limit: int = 10) -> list[dict]:
    """Runs of flagged rows (merging gaps up to ``gap`` rows), largest residual energy first."""
    windows, start, last = [], None, None
    for i in torch.nonzero(flagged).flatten().tolist():
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


def _rule(name: str, kind: str, a: float) -> str:
    shown = f"|{name}|" if kind.startswith("abs") else name
    return f"{shown} {'>' if kind.endswith('gt') else '<'} {a:.4g}"
