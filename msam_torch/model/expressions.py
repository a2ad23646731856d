"""Whitelisted arithmetic expressions for components, adjustments and parameters.

Expressions are parsed with :mod:`ast` and interpreted node by node; nothing is ever passed to
``eval``. Allowed: numbers, names, ``+ - * / ** ^`` (``^`` means power), unary minus, brackets
and the functions in :data:`FUNCTIONS`. Anything else raises :class:`~msam_torch.errors.ConfigError`,
as do numbers beyond float64, nesting deeper than :data:`MAX_DEPTH` and, for a number such as a
nominal theta, an evaluation that divides by zero, overflows or ends complex or non-finite.
"""
from __future__ import annotations

import ast
import math
import warnings
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Mapping

import torch

from msam_torch.errors import ConfigError

FUNCTIONS: dict[str, Callable] = {
    "abs": torch.abs,
    "sign": torch.sign,
    "sqrt": torch.sqrt,
    "exp": torch.exp,
    "log": torch.log,
    "sin": torch.sin,
    "cos": torch.cos,
    "tanh": torch.tanh,
}
_BINARY = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
    ast.Pow: lambda a, b: a**b,
}
_MAX_LENGTH = 500
MAX_DEPTH = 100


@dataclass(frozen=True)
class Expression:
    """A parsed expression: its source text, the signals it reads (``names``), its syntax tree and
    the constants it reads by name (``constants``: a model parameter in a term, at its value)."""

    text: str
    names: frozenset[str]
    tree: ast.AST
    key: str = ""
    constants: tuple[tuple[str, float], ...] = ()

    def __call__(self, values: Mapping[str, torch.Tensor | float]):
        """Evaluate with ``values`` bound to the names (tensors or floats). Division by zero,
        overflow and a complex value raise :class:`ConfigError` naming the key; so does a
        non-finite number (tensors over data are checked where the data are, see data.py)."""
        values = {**dict(self.constants), **values} if self.constants else values
        try:
            value = self._evaluate(values)
        except ArithmeticError as exc:
            reason = {ZeroDivisionError: "division by zero", OverflowError: "overflow beyond float64"}.get(type(exc), exc)
            raise ConfigError(self.key, f"{self.text!r}{self._with(values)} cannot be evaluated: {reason}") from None
        if not torch.is_tensor(value) or value.dim() == 0:
            if not math.isfinite(float(value)):
                raise ConfigError(self.key, f"{self.text!r}{self._with(values)} is {float(value)}, not a finite number")
        return value

    @cached_property
    def _evaluate(self) -> Callable:
        """The tree as nested closures, built once: the operations of interpreting it node by node,
        in the same order, without the interpretation (a simulation evaluates an expression at
        every stage)."""
        return _compile(self.tree)

    def _with(self, values) -> str:
        """`` with m = 0`` for the scalar values the expression read."""
        shown = [f"{n} = {values[n]:g}" for n in sorted(self.names) if isinstance(values.get(n), (int, float))]
        return f" (with {', '.join(shown)})" if shown else ""

    @property
    def is_magnitude(self) -> bool:
        """True when the whole expression is ``abs(...)``: adjusted as ``|f|^gamma``."""
        node = self.tree
        return isinstance(node, ast.Call) and node.func.id == "abs"

    @property
    def inner_text(self) -> str:
        """The argument of a top-level ``abs(...)``, else the whole text."""
        if self.is_magnitude:
            return ast.unparse(self.tree.args[0])
        return self.text


def parse(text, key: str, allowed: frozenset[str] | set[str], constants: Mapping[str, float] | None = None) -> Expression:
    """Parse ``text`` admitting only names in ``allowed`` and ``constants`` (named numbers, bound at
    evaluation and not among the names it reads); errors name the config ``key``."""
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ConfigError(key, f"expected an expression or a number, got {type(text).__name__}")
    text = str(text).strip()
    if not text:
        raise ConfigError(key, "empty expression")
    if len(text) > _MAX_LENGTH:
        raise ConfigError(key, f"expression longer than {_MAX_LENGTH} characters")
    try:  # '^' is power with power's precedence (Python would parse it as a low-precedence XOR)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SyntaxWarning of 'is' with a literal and the like
            tree = ast.parse(text.replace("^", "**"), mode="eval").body
    except (SyntaxError, ValueError) as exc:
        raise ConfigError(key, f"cannot parse expression {text!r}: {exc.msg if hasattr(exc, 'msg') else exc}") from None
    except (RecursionError, MemoryError):
        raise ConfigError(key, f"expression {text!r} is nested too deeply") from None
    names: set[str] = set()
    constants = dict(constants or {})
    _check(tree, key, text, frozenset(allowed) | frozenset(constants), names)
    read = tuple(sorted((n, float(constants[n])) for n in names if n in constants))
    return Expression(text, frozenset(n for n in names if n not in constants), tree, key, read)


def _check(node, key, text, allowed, names, depth=0):
    if depth > MAX_DEPTH:
        raise ConfigError(key, f"expression {text!r} is nested deeper than {MAX_DEPTH} levels")
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ConfigError(key, f"only numbers are allowed as constants in {text!r}")
        try:
            finite = math.isfinite(float(node.value))
        except OverflowError:
            finite = False
        if not finite:
            raise ConfigError(key, f"number beyond float64 in {text!r}")
    elif isinstance(node, ast.Name):
        if node.id not in allowed:
            known = ", ".join(sorted(allowed)) or "none"
            raise ConfigError(key, f"unknown name {node.id!r} in {text!r} (known: {known})")
        names.add(node.id)
    elif isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        _check(node.left, key, text, allowed, names, depth + 1)
        _check(node.right, key, text, allowed, names, depth + 1)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check(node.operand, key, text, allowed, names, depth + 1)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            raise ConfigError(key, f"function not allowed in {text!r} (allowed: {', '.join(FUNCTIONS)})")
        if len(node.args) != 1 or node.keywords:
            raise ConfigError(key, f"{node.func.id}() takes exactly one argument in {text!r}")
        _check(node.args[0], key, text, allowed, names, depth + 1)
    else:
        raise ConfigError(key, f"{type(node).__name__} is not allowed in {text!r}")


def _compile(node) -> Callable:
    if isinstance(node, ast.Constant):
        number = float(node.value)
        return lambda values: number
    if isinstance(node, ast.Name):
        name = node.id
        return lambda values: values[name]
    if isinstance(node, ast.BinOp):
        operation, left, right = _BINARY[type(node.op)], _compile(node.left), _compile(node.right)

        def binary(values):
            value = operation(left(values), right(values))
            if isinstance(value, complex):
                raise ArithmeticError("a complex value")  # noqa: TRY004 (reported by Expression.__call__)
            return value
        return binary
    if isinstance(node, ast.UnaryOp):
        operand = _compile(node.operand)
        return (lambda values: -operand(values)) if isinstance(node.op, ast.USub) else operand
    function, argument = FUNCTIONS[node.func.id], _compile(node.args[0])

    def call(values):
        value = argument(values)
        return function(value if torch.is_tensor(value) else torch.tensor(value, dtype=torch.float64))
    return call
