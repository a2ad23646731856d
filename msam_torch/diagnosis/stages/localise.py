"""Where the gap lies: the state-space region and time windows where the starting model fails.

For every one-signal rule ``R`` (``s > a``, ``s < a``, ``|s| > a``, ``|s| < a``, ``a`` on a grid of
quantiles), the starting structure is fitted separately inside and outside ``R`` on the one-step
rows (estimated derivative), each regime with theta free plus an offset and a ``sign(s)`` term so
that piecewise-affine changes (an engaging spring, a friction offset) are captured exactly; all
rules are fitted as one batch. The rule whose two-regime fit removes the most squared residual is
where the model changes behaviour. Of its two sides, the one where the plain starting structure
fits better (per row) is where the model holds; the other side's rows are flagged (when the split
removes at least ``MIN_EXPLAINED`` of the single-fit residual) and merged into time windows.
With ``orient="global"`` the failing side is the one where the structure fitted to *all* rows
misses more per row: the question for a model already adapted ("where does it still miss?"),
whose fit on a small region alone (a level pinned at a limit) can look perfect.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import torch

from msam_torch.diagnosis.stages.structure import relevant
from msam_torch.engine.candidates import EquationData
from msam_torch.engine.step import lstsq, solve_normal
from msam_torch.model.spec import Equation

MIN_EXPLAINED = 0.2
MIN_SHARE = 0.1  # each regime holds at least this share of the rows
FLIP = {"gt": "lt", "lt": "gt", "abs_gt": "abs_lt", "abs_lt": "abs_gt"}


@dataclass(frozen=True)
class Region:
    signal: str
    rule: str  # e.g. '|x| > 0.8'
    kind: str  # 'gt', 'lt', 'abs_gt', 'abs_lt'
    value: float
    share: float  # fraction of the rows inside
    explained: float  # share of the single-fit squared residual the two-regime fit removes

    def mask(self, values: torch.Tensor) -> torch.Tensor:
        v = values.abs() if self.kind.startswith("abs") else values
        return v > self.value if self.kind.endswith("gt") else v < self.value

    def flipped(self) -> "Region":
        kind = FLIP[self.kind]
        return replace(self, kind=kind, rule=_rule(self.signal, kind, self.value), share=1 - self.share)


def _sse(design: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted least-squares residual sum of squares of the ``design`` (M, K) for every row of
    ``weights`` (R, M) -> (R,): the normal equations of all rows from one product of the weights
    with the rows' outer products, the residuals from the solutions (not from the normal equations)."""
    k = design.shape[-1]
    outer = (design.unsqueeze(-1) * design.unsqueeze(-2)).flatten(-2)  # (M, K * K)
    x = solve_normal((weights @ outer).unflatten(-1, (k, k)), weights @ (design * y.unsqueeze(-1)))
    return (weights * (y - x @ design.mT) ** 2).sum(-1)


def _candidates(values: dict[str, torch.Tensor], quantiles: int, dtype) -> list[Region]:
    levels = torch.linspace(0.025, 0.975, quantiles, dtype=dtype)
    rules = []
    for name, v in values.items():
        for kind in ("gt", "lt", "abs_gt", "abs_lt"):
            base = v.abs() if kind.startswith("abs") else v
            for a in torch.quantile(base, levels).tolist():
                region = Region(name, _rule(name, kind, a), kind, a, 0.0, 0.0)
                share = float(region.mask(v).double().mean())
                if MIN_SHARE <= share <= 1 - MIN_SHARE:
                    rules.append(replace(region, share=share))
    return rules


def localise(design: torch.Tensor, y: torch.Tensor, values: dict[str, torch.Tensor], quantiles: int = 39,
             orient: str = "separate"):
    """``(regions, flagged, residual, explained)``: the best rule per signal (oriented to the side
    where the model fails, judged by a ``separate`` fit on each side or the ``global`` fit), the
    flagged rows (M,), the residual of the plain structure fitted where it holds, and the squared
    residual the best split removes."""
    tiny = torch.finfo(y.dtype).tiny
    total = _sse(design, y, torch.ones_like(y).unsqueeze(0))[0].clamp_min(tiny)
    rules = _candidates(values, quantiles, y.dtype)
    if not rules:
        return [], torch.zeros_like(y, dtype=torch.bool), y - design @ lstsq(design, y), 0.0
    inside = torch.stack([r.mask(values[r.signal]) for r in rules]).to(y.dtype)  # (R, M)
    explained = torch.empty(len(rules), dtype=y.dtype, device=y.device)
    for signal in dict.fromkeys(r.signal for r in rules):  # the rules of one signal share their design
        of = torch.tensor([r.signal == signal for r in rules], device=y.device)
        augmented = _augmented(design, values, signal)
        explained[of] = 1 - (_sse(augmented, y, inside[of]) + _sse(augmented, y, 1 - inside[of])) / total
    rows_in = inside.sum(-1)
    if orient == "global":
        squared = (y - design @ lstsq(design, y)) ** 2
        plain_in, plain_out = inside @ squared / rows_in, (1 - inside) @ squared / (len(y) - rows_in)
    else:
        plain_in = _sse(design, y, inside) / rows_in
        plain_out = _sse(design, y, 1 - inside) / (len(y) - rows_in)
    fails_inside = plain_in > plain_out
    oriented = [r if bool(fails_inside[k]) else r.flipped() for k, r in enumerate(rules)]
    best_per_signal = {}
    for k, r in enumerate(oriented):
        score = float(explained[k])
        if r.signal not in best_per_signal or score > best_per_signal[r.signal].explained:
            best_per_signal[r.signal] = replace(r, explained=score)
    regions = sorted(best_per_signal.values(), key=lambda r: -r.explained)
    best = regions[0]
    flagged = best.mask(values[best.signal])
    if best.explained < MIN_EXPLAINED:
        flagged = torch.zeros_like(flagged)
    holds = (~best.mask(values[best.signal])).to(y.dtype).sqrt()
    residual = y - design @ lstsq(design * holds.unsqueeze(-1), y * holds)
    return regions, flagged, residual, best.explained


def where(t: torch.Tensor, design: torch.Tensor, y: torch.Tensor, values: dict[str, torch.Tensor],
          orient: str = "separate", held: tuple | None = None) -> dict:
    """:func:`localise` as the report's ``where`` (``summary``: flagged fraction, time windows,
    regions, the single fit's residual and target RMS, and with ``held`` rows the share of their
    squared residual the best rule's split removes, :func:`confirmed`) and the ``series`` its plots draw."""
    regions, flagged, residual, explained = localise(design, y, values, orient=orient)
    single = lstsq(design, y)
    held_out = confirmed(design, y, values, single, regions[0], held) if held and regions else None
    summary = {"flagged_fraction": float(flagged.double().mean()), "split_explained": explained,
               "residual_rms": float((y - design @ single).square().mean().sqrt()),
               "target_rms": float(y.square().mean().sqrt()),
               "held_out_explained": held_out,
               "time_windows": time_windows(t, flagged, residual), "regions": [asdict(r) for r in regions]}
    return {"summary": summary, "series": {"t": t, "residual": residual, "flagged": flagged, "values": values}}


def confirmed(design: torch.Tensor, y: torch.Tensor, values: dict, single: torch.Tensor, region: Region,
              held: tuple) -> float:
    """The share of the squared residual of ``held`` rows (design, target, values) left by the
    ``single`` fit that ``region``'s two-regime fit removes, every fit made on the rows ``design``,
    ``y`` (an offset and a sign term per regime, as in :func:`localise`): the split chosen in-sample,
    judged out of sample."""
    held_design, held_y, held_values = held
    total = (held_y - held_design @ single).square().sum().clamp_min(torch.finfo(y.dtype).tiny)
    train, test = _augmented(design, values, region.signal), _augmented(held_design, held_values, region.signal)
    inside, held_inside = region.mask(values[region.signal]), region.mask(held_values[region.signal])
    fit = lambda rows: lstsq(train[rows], y[rows]) if bool(rows.any()) else train.new_zeros(train.shape[-1])
    predicted = torch.where(held_inside, test @ fit(inside), test @ fit(~inside))
    return float(1 - (held_y - predicted).square().sum() / total)


def starting_where(equation: Equation, signals: dict, held_out: dict | None = None) -> dict:
    """:func:`where` the starting structure fails, on the one-step (pointwise) rows of the training
    record (its split judged on ``held_out``'s rows, where given); pointwise, because a weak-form
    row mixes the states over its test function's window."""
    rows = lambda s: EquationData.build(equation, s, "none")
    design = lambda d: torch.cat([d.components[0], d.fixed_components[0]], -1)
    data = rows(signals)
    held = None
    if held_out is not None and equation.target in held_out:
        other = rows(held_out)
        held = (design(other), other.y[0], signal_values(equation, held_out))
    return where(signals["t"], design(data), data.y[0], signal_values(equation, signals), held=held)


def signal_values(equation: Equation, signals: dict) -> dict:
    """The signals an equation reads (its target and time left out), by name."""
    return {n: signals[n] for n in sorted(equation.signals - {equation.target, "t"}) if n in signals}


def time_windows(t: torch.Tensor, flagged: torch.Tensor, residual: torch.Tensor, gap: int = 1) -> list[dict]:
    """Every run of flagged rows (merging gaps up to ``gap`` rows), largest residual energy first."""
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
    return sorted(found, key=lambda w: -w["energy_share"])


def _augmented(design: torch.Tensor, values: dict, signal: str) -> torch.Tensor:
    """``design`` with an offset and a ``sign(signal)`` column: one regime of a split."""
    return torch.cat([design, torch.ones_like(design[..., :1]), torch.sign(values[signal]).unsqueeze(-1)], -1)


def _rule(name: str, kind: str, a: float) -> str:
    shown = f"|{name}|" if kind.startswith("abs") else name
    return f"{shown} {'>' if kind.endswith('gt') else '<'} {a:.4g}"


def located(equation: Equation, summary: dict, relative: float, absolute: float) -> str | None:
    """The gap :func:`where` finds on one-step rows, as a reason, or None: rows are flagged (a split
    removes at least :data:`MIN_EXPLAINED` of the squared residual), and so does the same split on
    the held-out rows where there are any, by a share relevant by the null rule's margins
    (:func:`~msam_torch.diagnosis.stages.structure.relevant`). The fixed
    components that read the region's signal are named: an effect on them is not a hypothesis while
    they are fixed (the diagnosis then tests them adjustable,
    :func:`~msam_torch.diagnosis.stages.equation.freed`)."""
    shares = [summary["split_explained"], summary.get("held_out_explained")]
    if not summary["flagged_fraction"] or any(share is not None and (
            share < MIN_EXPLAINED or not relevant(share, summary["residual_rms"], summary["target_rms"], relative,
                                                  absolute)) for share in shares):
        return None
    region = summary["regions"][0]
    held = summary.get("held_out_explained")
    text = (f"the starting model fails where {region['rule']} (a separate fit there removes "
            f"{100 * summary['split_explained']:.0f} % of the squared residual"
            f"{'' if held is None else f', {100 * held:.0f} % on held-out rows'}) and no hypothesis closes the gap")
    fixed = [equation.components[i].term.text for i in implicated(equation, summary)]
    if fixed:
        text += (f"; {region['signal']} enters through the fixed component{'s' if len(fixed) > 1 else ''} "
                 f"{', '.join(fixed)}, whose effects (saturation, a dead zone) no hypothesis tests while fixed")
    return text


def implicated(equation: Equation, summary: dict) -> list[int]:
    """The fixed components that read the signal of the best region :func:`where` found: an effect
    on them (saturation, a dead zone) is no hypothesis while they are fixed."""
    if not summary.get("regions"):
        return []
    signal = summary["regions"][0]["signal"]
    return [i for i in equation.fixed if signal in equation.components[i].term.names]
