"""Candidate explanations of a gap in one state equation, fitted together as a batch.

Every hypothesis is a candidate (Eq. 8-9) of one *extended* equation: the starting components,
a copy of every adjustable component, a constant component, and the adjustment set F plus two
constant functions, ``1`` (component left as it is) and ``0`` (copy switched off). So one batch holds

- ``retuned``: the starting model with every theta re-fitted (the null hypothesis);
- ``multiplicative``: one component adjusted, ``M_i -> M_i |f|^gamma`` (the paper's Eq. 8);
- ``additive``: one component split into two copies (docs/design.md section 3): the original
  ``theta_i M_i`` and a copy ``theta_i' M_i |f|^gamma`` with its own exponent and theta, started
  at several exponents away from 0 (at 0 the copies coincide and never separate);
- ``exchange``: an additive copy ``theta_i' s|s|^gamma`` of a signal ``s`` that the equation
  exchanges with a reference ``r`` of the same quantity (``-h (T - Ta)``: heat with the ambient),
  plus a fitted constant and a fitted multiple of ``r^2``: the law of an exchange is
  ``c (s|s|^gamma - r|r|^gamma)``, and the reference's part is, to second order in the reference's
  variation, a constant, a linear term that its own component already carries and a square (the
  units of ``s`` and ``r`` may differ: each term has its own theta). Without the constant the
  copy's exponent bends to mimic it; without the square, to mimic the curvature of the
  reference's law where the reference varies (an ambient temperature drifting by a few kelvin
  moves ``Ta^4`` by as much as the curvature of ``T^4`` that tells the exponent);
- ``offset``: the starting model plus a fitted constant (a sensor or actuator offset, a constant
  load), in an equation that holds no constant component and whose signals all take both signs
  (:func:`offset_testable`): measured records often carry an offset, and a power law fitted without
  it bends to mimic it (docs/diagnose.md).

The fit is variable projection (theta re-solved every step) with damped Gauss-Newton steps on
gamma, taken by :func:`msam_torch.engine.step.step` on all trials and hypotheses at once.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from msam_torch.diagnosis.stages.rows import WeakForm
from msam_torch.engine.candidates import EquationData, Selection, columns, predict
from msam_torch.engine.step import evaluate, step
from msam_torch.engine.values import State, StepOptions
from msam_torch.model.expressions import parse
from msam_torch.model.notation import format_component, format_equation
from msam_torch.model.spec import Component, Equation

ADDITIVE_STARTS = (-0.5, 0.5, 1.5)
COLLINEAR = 0.15  # |gamma| of an additive copy below which it is a log pair of its original (rejected)
SANE_EXPONENT = 5.0  # |gamma| beyond which a fit ran away (catalogued laws need at most 3)
COPIES = ("additive", "exchange")  # kinds whose exponent sits in a copy's slot
EXPONENTLESS = ("retuned", "offset")  # kinds without an exponent of their own
MINORITY_SIGN = 0.1  # share of the samples a signal must hold on either side of 0 for an offset to be tested


@dataclass(frozen=True)
class Hypothesis:
    """One candidate explanation: ``kind``, the component (index in the equation), the function."""

    kind: str  # 'retuned', 'multiplicative', 'additive', 'exchange' or 'offset'
    component: int | None = None
    function: int | None = None
    start: float = 0.0
    references: tuple[str, ...] = ()  # an exchange's references (signals its component exchanges with)

    @property
    def form(self) -> tuple:
        """(kind, component, function): the starts of one form are the same hypothesis fitted from
        different exponents."""
        return self.kind, self.component, self.function

    def label(self, equation: Equation) -> str:
        if self.kind == "retuned":
            return "starting model, theta re-fitted"
        if self.kind == "offset":
            return "starting model + constant"
        term = format_component(equation, self.component, None, None)
        f = equation.adjustments[self.function].text
        if self.kind == "multiplicative":
            return f"{term} -> {term}*{f}^gamma"
        if self.kind == "exchange":
            return f"{term} + {term}*{f}^gamma + constant" + "".join(f" + {r}^2" for r in self.references)
        return f"{term} + {term}*{f}^gamma"


def references(hypotheses: list[Hypothesis]) -> tuple[str, ...] | None:
    """The exchange hypotheses' references, in order (None without exchange hypotheses)."""
    exchanges = [h for h in hypotheses if h.kind == "exchange"]
    return tuple(sorted({r for h in exchanges for r in h.references})) if exchanges else None


def extended_equation(equation: Equation, references: tuple[str, ...] | None = None) -> Equation:
    """Starting components + a copy of every adjustable one + the constant ``1`` (+, for exchange
    hypotheses with ``references`` (:func:`references`), the square of each reference); F + the
    constants 1 and 0."""
    copies = tuple(replace(equation.components[i], adjustable=True) for i in equation.adjustable)
    constants = (parse("1", "diagnose", set()), parse("0", "diagnose", set()))
    constant_terms = (Component(term=constants[0], theta=constants[1]),) + tuple(
        Component(term=parse(f"{r}^2", "diagnose", {r}), theta=constants[1]) for r in references or ())
    return Equation(equation.target, equation.components + copies + constant_terms, equation.adjustments + constants)


def offset_testable(equation: Equation, signals: dict) -> bool:
    """Whether an offset can be told apart in ``equation`` on the record ``signals``: the equation
    holds no constant (:func:`holds_constant`) and each signal it reads (the target aside) takes
    either sign in at least :data:`MINORITY_SIGN` of the samples. Where a signal keeps one sign,
    a constant is a law of it (``s|s|^-1``), and what is odd in two-signed data (a dead zone or
    saturation of a one-signed input, Coulomb friction in one direction) reads as an offset."""
    if holds_constant(equation):
        return False
    for name in equation.signals - {equation.target, "t"}:
        values = signals[name]
        if float(torch.minimum((values > 0).double().mean(), (values < 0).double().mean())) < MINORITY_SIGN:
            return False
    return True


def holds_constant(equation: Equation) -> bool:
    """Whether a component of ``equation`` is a constant (it carries an offset already)."""
    return any(not c.term.names for c in equation.components)


def enumerate_hypotheses(equation: Equation, exchanging: dict[int, tuple[str, ...]] | None = None,
                         starts=ADDITIVE_STARTS, offset: bool = False) -> list[Hypothesis]:
    """Every hypothesis of ``equation``; ``exchanging``: the components with exchange references
    (:meth:`~msam_torch.diagnosis.catalogue.entries.Roles.exchanging`), each also tried as an exchange law of its own signal;
    ``offset``: the offset too (:func:`offset_testable`)."""
    found = [Hypothesis("retuned")]
    for i in equation.adjustable:
        for f in range(len(equation.adjustments)):
            found.append(Hypothesis("multiplicative", i, f))
    for i in equation.adjustable:
        for f in range(len(equation.adjustments)):
            found.extend(Hypothesis("additive", i, f, s) for s in starts)
    for i, partners in (exchanging or {}).items():
        for f, a in enumerate(equation.adjustments):
            if a.is_magnitude and a.inner_text == equation.components[i].term.text:
                found.extend(Hypothesis("exchange", i, f, s, partners) for s in starts)
    return found + ([Hypothesis("offset")] if offset else [])


def encode(equation: Equation, hypotheses: list[Hypothesis], device=None):
    """Choices (C, 2Q + 1 [+ R]) into the extended adjustment set, and starting exponents: the slots
    of the components, of their copies, of the constant and, with exchange hypotheses, of the R
    references' squares (:func:`extended_equation`)."""
    q, n_f = len(equation.adjustable), len(equation.adjustments)
    one, zero = n_f, n_f + 1
    shared = references(hypotheses)
    width = 2 * q + 1 + (0 if shared is None else len(shared))
    choices = torch.full((len(hypotheses), width), zero, dtype=torch.long)
    choices[:, :q] = one
    starts = torch.zeros(len(hypotheses), width, dtype=torch.float64)
    slot = {i: k for k, i in enumerate(equation.adjustable)}
    for c, h in enumerate(hypotheses):
        if h.kind == "multiplicative":
            choices[c, slot[h.component]] = h.function
        elif h.kind in COPIES:
            choices[c, q + slot[h.component]] = h.function
            starts[c, q + slot[h.component]] = h.start
        if h.kind in ("exchange", "offset"):
            choices[c, 2 * q] = one
        if h.kind == "exchange":
            for r in h.references:
                choices[c, 2 * q + 1 + shared.index(r)] = one
    return choices.to(device), starts.to(device)


@dataclass(frozen=True)
class Fitted:
    """Exponents and theta of every trial and hypothesis: (T, C, 2Q), (T, C, 2Q), (T, C, P)."""

    gamma: torch.Tensor
    theta: torch.Tensor
    theta_fixed: torch.Tensor
    fitness: torch.Tensor  # (T, C) best fitness (Eq. 19) on the fitted rows
    invalid: torch.Tensor  # (T, C) diverged, non-finite or a log pair


def fit(data: EquationData, choices: torch.Tensor, start: torch.Tensor, options: StepOptions, steps: int,
        q: int, exclude_start: bool = False) -> Fitted:
    """Iterate the step on every trial and hypothesis; keep each one's best state (Algorithm 1);
    ``q`` adjustable components (slots q to 2q are their additive copies, :func:`encode`).
    ``exclude_start``: ``start`` was fitted to rows that ``data`` leaves out (a cross-fit's held-out
    block), so the best state is chosen among the stepped ones: kept as a candidate, the start
    predicts the block from a fit that saw it wherever no step beats it by Eq. 19.
    """
    selection = data.select(choices)
    t = selection.y.shape[0]
    gamma = start.expand((t,) + choices.shape).to(selection.y.dtype).clone()
    zeros = lambda k: gamma.new_zeros(gamma.shape[:-1] + (k,))
    state = State(gamma, zeros(gamma.shape[-1]), zeros(selection.fixed_components.shape[-1]),
                  torch.zeros(gamma.shape[:-1], dtype=torch.bool, device=gamma.device))
    current = evaluate(selection, state, options)
    best_fitness = torch.full_like(current.fitness, -torch.inf) if exclude_start and steps else current.fitness
    best_gamma = state.gamma
    for _ in range(steps):
        state = step(selection, state, current, options).state
        current = evaluate(selection, state, options)
        improved = current.fitness > best_fitness
        best_fitness = torch.where(improved, current.fitness, best_fitness)
        best_gamma = torch.where(improved.unsqueeze(-1), state.gamma, best_gamma)
    final = evaluate(selection, replace(state, gamma=best_gamma), options) if steps else current
    copy_on = choices[:, q:2 * q] < data.log_f.shape[-1] - 2  # additive slots in use
    log_pair = (copy_on & (best_gamma[..., q:2 * q].abs() < COLLINEAR)).any(-1)
    invalid = state.diverged | ~torch.isfinite(best_fitness) | log_pair
    return Fitted(best_gamma, final.theta, final.theta_fixed, best_fitness, invalid)


def sane(fitted: Fitted) -> torch.Tensor:
    """(T, C): every exponent within :data:`SANE_EXPONENT` (a fit beyond it ran away, not an effect)."""
    return (fitted.gamma.abs() <= SANE_EXPONENT).all(-1)


def predict_rows(data: EquationData, choices: torch.Tensor, fitted: Fitted) -> torch.Tensor:
    """Output of every trial and hypothesis on ``data`` (e.g. held-out rows): (T, C, M)."""
    selection: Selection = data.select(choices)
    cols = columns(selection, fitted.gamma)
    return predict(selection, cols, fitted.theta, fitted.theta_fixed)


def crossed_errors(weak: WeakForm, choices: torch.Tensor, start: torch.Tensor, options: StepOptions, steps: int,
                   q: int, folds: int, reach: int) -> torch.Tensor:
    """Errors (C, M) of every hypothesis on the fitted training rows, each row predicted by a fit of
    the other ``folds`` blocks (:meth:`~msam_torch.diagnosis.stages.rows.WeakForm.folds`; ``steps`` steps from the exponents
    ``start`` (C, 2Q), the full fit's, which saw the block, so never kept; 0: theta alone)."""
    fold, weights = weak.folds(folds, reach)
    crossed = fit(weak.weighted(weights, torch.zeros_like(weights)), choices, start, options, steps, q, exclude_start=True)
    rows = predict_rows(weak.data, choices, crossed)  # (folds, C, M); unweighted on the fitted rows
    fitted = torch.nonzero(fold >= 0).squeeze(-1)
    return rows[fold[fitted], :, fitted].T - weak.data.y[0][fitted]


def heldout_errors(val_data: EquationData, val_rows: torch.Tensor, choices: torch.Tensor, fitted: Fitted) -> torch.Tensor:
    """Prediction errors of every trial and hypothesis on the held-out rows (T, C, M')."""
    return predict_rows(val_data, choices, fitted)[..., val_rows] - val_data.y[0][val_rows]


def heldout_rmse(errors: torch.Tensor, fitted: Fitted) -> torch.Tensor:
    """RMSE (T, C) of the held-out ``errors`` (:func:`heldout_errors`); invalid fits score inf."""
    rmse = torch.sqrt((errors**2).mean(-1))
    return torch.where(fitted.invalid | ~torch.isfinite(rmse), torch.full_like(rmse, torch.inf), rmse)


def slot(equation: Equation, h: Hypothesis) -> int:
    """The exponent slot of hypothesis ``h`` among the extended equation's 2Q adjustable slots."""
    q = len(equation.adjustable)
    return equation.adjustable.index(h.component) + (q if h.kind in COPIES else 0)


def exponent(h: Hypothesis, equation: Equation, gamma: torch.Tensor) -> float | None:
    """The fitted exponent of an effect hypothesis (None for the re-fitted start and the offset)."""
    return None if h.kind in EXPONENTLESS else float(gamma[slot(equation, h)])


def data_theta(fitted: Fitted, c: int, choices: torch.Tensor, scale: torch.Tensor, trial: int = 0) -> torch.Tensor:
    """Theta in the data's units: the normalisation ``|f/s|^gamma`` folded back (``s^-gamma``)."""
    return fitted.theta[trial, c] * scale[choices[c]] ** (-fitted.gamma[trial, c])


def equation_text(extended: Equation, equation: Equation, choice, gamma, theta, theta_fixed) -> str:
    """The hypothesis as an equation in the paper's notation (switched-off copies left out)."""
    n_f = len(equation.adjustments)
    slots = {i: k for k, i in enumerate(extended.adjustable)}
    fixed = {i: k for k, i in enumerate(extended.fixed)}
    thetas, terms = [], []
    for i in range(len(extended.components)):
        if i in fixed:
            thetas.append(float(theta_fixed[fixed[i]]))
            terms.append(format_component(extended, i, None, None))
            continue
        k = slots[i]
        f = int(choice[k])
        if f == n_f + 1:
            continue
        thetas.append(float(theta[k]))
        terms.append(format_component(extended, i, None if f == n_f else f, float(gamma[k])))
    return format_equation(equation.target, thetas, terms)


def fitted_text(extended: Equation, equation: Equation, choices: torch.Tensor, fitted: Fitted, c: int,
                scale: torch.Tensor) -> str:
    """:func:`equation_text` of hypothesis ``c`` of the first trial, theta in the data's units."""
    return equation_text(extended, equation, choices[c], fitted.gamma[0, c], data_theta(fitted, c, choices, scale),
                         fitted.theta_fixed[0, c])
