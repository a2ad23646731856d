"""Strategies behind names: one :class:`Registry` per kind of strategy, and the config field type
that names one (:class:`Strategy`).

A kind of strategy is a ``typing.Protocol`` (a derivative estimator, a step-size rule, an
evaluator); its registry maps each config name to a factory that makes one. A config field
of type ``Annotated[object, Strategy(kind)]`` takes a name or an object; names become objects in
one place, :func:`msam_torch.run.plan.prepare`, where an unknown name is an error that lists the
registered ones, so a name registered later is accepted and shown like the built-in ones.

A factory is a zero-argument callable (usually the strategy's class), registered where the
strategy is defined (or, for the evaluators, in :mod:`msam_torch.run.evaluators`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Generic, TypeVar

from pydantic_core import core_schema

from msam_torch.errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    """Named factories of one kind of strategy; ``key`` is the config key that names one."""

    def __init__(self, key: str, protocol: type, kind: str):
        self.key = key
        self.protocol = protocol
        self.kind = kind
        self._factories: dict[str, Callable[[], T]] = {}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._factories)

    def register(self, name: str, factory: Callable[[], T]):
        """Make ``factory`` (a class or a zero-argument callable) the strategy called ``name``;
        returns ``factory``."""
        self._factories[name] = factory
        return factory

    def create(self, name: str) -> T:
        """A new strategy of the registered ``name``."""
        if name not in self._factories:
            raise ConfigError(self.key, self.unknown(name))
        return self._factories[name]()

    def resolve(self, value: str | T) -> T:
        """The strategy named by ``value``, or ``value`` itself when it is already one."""
        if isinstance(value, str):
            return self.create(value)
        if not isinstance(value, self.protocol):
            raise ConfigError(self.key, self.not_a_strategy(value))
        return value

    def unknown(self, name: str) -> str:
        return f"unknown {self.kind} {name!r} (known: {', '.join(self.names)})"

    def not_a_strategy(self, value) -> str:
        return (f"expected the name of a {self.kind} ({', '.join(self.names)}) or an object with the methods of "
                f"{self.protocol.__name__}, got {type(value).__name__}")


def label(value) -> str:
    """A strategy as the config writes it: its name (``name`` attribute, else its type's name)."""
    return value if isinstance(value, str) else getattr(value, "name", type(value).__name__)


@dataclass(frozen=True)
class Strategy:
    """Pydantic field annotation of a key that names a strategy of ``kind``: a name or, from Python,
    an object that is one. Loading the config checks only that much (the registries live with the
    strategies, above the config); the name is looked up in its :class:`Registry` when the config
    is planned (:func:`msam_torch.run.plan.prepare`, before any data is read), where an unknown name
    is an error listing the known ones. An object is kept as it is, and written as its ``name`` in
    JSON (``model_dump(mode="json")``: results, resolved configs)."""

    kind: str

    def _check(self, value):
        if isinstance(value, (bool, int, float, list, tuple, dict, type(None))):
            raise ValueError(f"expected the name of a {self.kind} or, from Python, a {self.kind} object, "
                             f"got {type(value).__name__}")
        return value

    def __get_pydantic_core_schema__(self, source, handler):
        return core_schema.no_info_plain_validator_function(
            self._check, serialization=core_schema.plain_serializer_function_ser_schema(label, when_used="json"))

    def __get_pydantic_json_schema__(self, schema, handler):
        return {"type": "string", "strategy": self.kind}  # the kind names its registry (run.plan.config_schema)
