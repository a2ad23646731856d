"""Threshold hypotheses: a component changed only beyond a threshold ``c`` of a signal ``s``
(docs/diagnose.md, "Threshold hypotheses"), where the localisation (:mod:`~msam_torch.diagnosis.stages.localise`)
finds the starting model failing on one side of a rule on ``s``. Three shapes (:data:`SHAPES`):

- ``hinge``: an added term ``theta' max(0, s - c)^(1 + gamma)`` (or ``max(0, c - s)``): an overflow,
  an end stop; its exponent is fitted by the same step as a power law's (Eq. 15-17);
- ``clip``: ``M(s) -> M(clip(s, -c, c))``: saturation of an input or a state;
- ``dead zone``: ``M(s) -> M(s - c sign(s))`` where ``|s| > c``, 0 inside.

The functions are exact (``relu``): ``c`` is never differentiated. It is profiled on a grid of
:data:`GRID` values between the record's quantiles of ``s`` (or ``|s|``) beyond which at least
:data:`LEAST_BEYOND` of the samples lie, each grid value fitted by the hypotheses' own step, and
the one that fits the training rows best (Eq. 19) kept. Its interval comes from block-bootstrap
trials of the same rows (:func:`~msam_torch.diagnosis.effects.bootstrap.block_weights`), each
trial's best grid value with theta re-fitted: two robust standard deviations about the fit, never
narrower than half a grid step (:func:`profile`).
"""
from __future__ import annotations

import ast
import copy
from dataclasses import dataclass, replace

import torch

from msam_torch.model.expressions import Expression, parse
from msam_torch.model.spec import Equation

GRID = 41  # threshold values tried per form
LEAST_BEYOND = 0.02  # share of the samples a threshold must leave beyond it (and 0.1 before it)
LEAST_BEFORE = 0.1
RELEVANT = 0.2  # share of the squared residual a localised rule's split removes for its signal to be tried


@dataclass(frozen=True)
class Shape:
    """How a threshold changes an equation: an added term of its own (``replaces`` False, with an
    exponent) or a component whose signal is replaced."""

    name: str
    replaces: bool
    sides: tuple[str, ...]

    def function(self, signal: str, c: str, side: str) -> str:
        """The thresholded signal (or the added term) as an expression of ``signal`` and the
        threshold ``c`` (a number or a name): ``relu(s - c)`` (``relu(c - s)`` below),
        ``s - relu(s - c) + relu(-s - c)`` (clip), ``relu(s - c) - relu(-s - c)`` (dead zone)."""
        above, below = f"relu({signal} - ({c}))", f"relu(-{signal} - ({c}))"
        if self.name == "hinge":
            return above if side == "upper" else f"relu(({c}) - {signal})"
        return f"({signal} - {above} + {below})" if self.name == "clip" else f"({above} - {below})"

    def levels(self, values: torch.Tensor, side: str) -> torch.Tensor:
        """The grid of thresholds on the record's ``values`` of the signal."""
        base = values if self.name == "hinge" else values.abs()
        low, high = (LEAST_BEFORE, 1 - LEAST_BEYOND) if side != "lower" else (LEAST_BEYOND, 1 - LEAST_BEFORE)
        ends = torch.quantile(base, torch.tensor([low, high], dtype=base.dtype, device=base.device))
        return torch.linspace(float(ends[0]), float(ends[1]), GRID, dtype=base.dtype)


SHAPES = {s.name: s for s in (Shape("hinge", False, ("upper", "lower")), Shape("clip", True, ("both",)),
                              Shape("dead zone", True, ("both",)))}


@dataclass(frozen=True)
class Threshold:
    """One threshold form at one value: the shape, its signal and side, the component it replaces
    (None for an added hinge), ``value`` = c, its bootstrap ``half_width`` and the signal's range."""

    shape: str
    signal: str
    side: str
    component: int | None
    value: float
    half_width: float = float("nan")
    span: float = float("nan")
    symbol: str | None = None  # a name standing for the value (a signal on the trials' axis, :mod:`.profile`)

    @property
    def form(self) -> tuple:
        return self.shape, self.signal, self.side, self.component

    @property
    def replaces(self) -> bool:
        return SHAPES[self.shape].replaces

    def term(self, equation: Equation) -> str:
        """The term this threshold adds: the hinge, or the replaced component with ``s``
        thresholded; at its value, or at its ``symbol``."""
        c = self.symbol or f"{self.value:.6g}"
        inner = ast.parse(SHAPES[self.shape].function(self.signal, c, self.side), mode="eval").body
        if self.component is None:
            return ast.unparse(inner)
        tree = ast.parse(ast.unparse(equation.components[self.component].term.tree), mode="eval").body
        return ast.unparse(_Swap(self.signal, inner).visit(tree))

    def expression(self, equation: Equation, signals: set[str]) -> Expression:
        """:meth:`term` parsed (reading ``signals`` and the replaced component's named constants)."""
        constants = {} if self.component is None else dict(equation.components[self.component].term.constants)
        return parse(self.term(equation), f"{equation.target}: threshold", signals, constants)

    def text(self) -> str:
        """``c`` as the report writes it."""
        shown = f"|{self.signal}|" if self.side == "both" else self.signal
        return f"{self.shape} at {shown} = {self.value:.4g}"


class _Swap(ast.NodeTransformer):
    """Replaces every name ``signal`` in a syntax tree by ``node``."""

    def __init__(self, signal: str, node: ast.AST):
        self.signal, self.node = signal, node

    def visit_Name(self, name: ast.Name) -> ast.AST:
        return copy.deepcopy(self.node) if name.id == self.signal else name


def forms(equation: Equation, summary: dict, signals: dict) -> list[Threshold]:
    """Every threshold form (at no value yet) on the signals of the relevant localised rules (each
    signal's best, :func:`~msam_torch.diagnosis.stages.localise.where`): those whose split removes at
    least :data:`RELEVANT` of the squared residual and at least half what the best rule's removes.
    Hinges on either side of each signal, and a clip and a dead zone of each component that reads it."""
    found, regions = [], summary.get("regions", [])
    for region in regions:
        s = region["signal"]
        if region["explained"] < max(RELEVANT, regions[0]["explained"] / 2) or s not in signals:
            continue
        for shape in SHAPES.values():
            readers = [i for i, c in enumerate(equation.components) if s in c.term.names] if shape.replaces else [None]
            found += [Threshold(shape.name, s, side, i, float("nan")) for i in readers for side in shape.sides]
    return found


def grids(found: list[Threshold], signals: dict) -> torch.Tensor:
    """The grid of each form of ``found`` (:meth:`Shape.levels`) on the record ``signals``: (GRID, K)."""
    return torch.stack([SHAPES[f.shape].levels(signals[f.signal], f.side) for f in found], -1)


def names(thresholds: list[Threshold]) -> set[str]:
    """The signals and symbols the thresholds' terms read."""
    return {t.signal for t in thresholds} | {t.symbol for t in thresholds if t.symbol}


def switchable(equation: Equation, thresholds: list[Threshold]) -> Equation:
    """``equation`` ready for threshold hypotheses: every fixed component a clip or dead zone
    replaces made adjustable with no adjustment function (so it can be switched off), each
    adjustable component's functions written out, and the hinges' functions ``abs(term)`` appended
    to the adjustment set (each taken by its own term only, :func:`hinge_function`)."""
    replaced = {t.component for t in thresholds if t.component is not None}
    components = tuple(
        replace(c, allowed=equation.allowed(i)) if c.adjustable else
        replace(c, adjustable=True, allowed=()) if i in replaced else c
        for i, c in enumerate(equation.components))
    hinges = tuple(dict.fromkeys(f"abs({t.term(equation)})" for t in thresholds if t.component is None))
    functions = tuple(parse(h, f"{equation.target}: {h}", names(thresholds)) for h in hinges)
    return replace(equation, components=components, adjustments=equation.adjustments + functions)


def hinge_function(equation: Equation, threshold: Threshold) -> int | None:
    """The index of a hinge's ``abs(term)`` in :func:`switchable`'s adjustment set (None for a replacement)."""
    if threshold.component is not None:
        return None
    return [f.text for f in equation.adjustments].index(f"abs({threshold.term(equation)})")


def best_per_form(thresholds: list[Threshold], score: torch.Tensor) -> dict[tuple, int]:
    """Per form, the index of its grid value of the highest ``score`` (C,) (ties: the first)."""
    best: dict[tuple, int] = {}
    for k, t in enumerate(thresholds):
        if t.form not in best or float(score[k]) > float(score[best[t.form]]):
            best[t.form] = k
    return best


def spread(values: list[float], fitted: float, step: float) -> float:
    """Half-width of a threshold's interval: two robust standard deviations (1.4826 median absolute
    deviations) of the trials' ``values`` about their median, plus how far that median is from the
    ``fitted`` value, at least half a grid ``step``."""
    if len(values) < 2:
        return float("inf")
    v = torch.tensor(values, dtype=torch.float64)
    median = float(v.median())
    return max(2.0 * 1.4826 * float((v - median).abs().median()) + abs(median - fitted), step / 2)
