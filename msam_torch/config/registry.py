"""Strategies behind names: one :class:`Registry` per kind of strategy, and the config field type
that names one (:class:`Choice`).

A kind of strategy is a ``typing.Protocol`` (a derivative estimator, a step-size rule, an
evaluator); its registry maps each config name to a factory that makes one. The config schema is
built from the registries: a config field of type ``Annotated[object, Choice(registry)]`` accepts a
registered name or an object that satisfies the protocol, its JSON schema lists the registered
names, and an unknown name is an error that lists them, so a name registered later is accepted and
shown like the built-in ones. Names become objects in one place, :mod:`msam_torch.prepare`.

A factory is a zero-argument callable (usually the strategy's class) or, for a strategy defined in
a module that itself depends on the config schema, its ``"module:attribute"`` path, imported the
first time that name is chosen (as a package entry point is).
"""
from __future__ import annotations

import importlib
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
        self._factories: dict[str, Callable[[], T] | str] = {}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._factories)

    def register(self, name: str, factory: Callable[[], T] | str):
        """Make ``factory`` (a class, a zero-argument callable or a ``"module:attribute"`` path)
        the strategy called ``name``; returns ``factory``, so it serves as a class decorator too."""
        self._factories[name] = factory
        return factory

    def create(self, name: str) -> T:
        """A new strategy of the registered ``name``."""
        if name not in self._factories:
            raise ConfigError(self.key, self.unknown(name))
        factory = self._factories[name]
        if isinstance(factory, str):
            module, _, attribute = factory.partition(":")
            factory = self._factories[name] = getattr(importlib.import_module(module), attribute)
        return factory()

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
class Choice:
    """Pydantic field annotation: a registered name of ``registry`` or an object satisfying its
    protocol. Names are checked against the registry when a config is validated; an object is kept
    as it is, and written as its ``name`` in JSON (``model_dump(mode="json")``: results, resolved configs)."""

    registry: Registry

    def _check(self, value):
        if isinstance(value, str):
            if value not in self.registry.names:
                raise ValueError(self.registry.unknown(value))
            return value
        if not isinstance(value, self.registry.protocol):
            raise ValueError(self.registry.not_a_strategy(value))
        return value

    def __get_pydantic_core_schema__(self, source, handler):
        return core_schema.no_info_plain_validator_function(
            self._check, serialization=core_schema.plain_serializer_function_ser_schema(label, when_used="json"))

    def __get_pydantic_json_schema__(self, schema, handler):
        return {"type": "string", "enum": list(self.registry.names)}
