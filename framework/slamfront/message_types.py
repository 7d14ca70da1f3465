"""Which message types a log reader knows: slamfront's own and those installed plugins declare.

A JSON message in a log names its type only by schema name (``slamfront.LoopResult``).
Tools that read logs decode it with the class registered for that name: the framework's
shared types (:data:`slamfront.messages.SHARED_MESSAGES`) and the types plugin packages
declare with the ``slamfront_message_types`` hook. A type is therefore known because its
package is installed (or named with ``-p``), never because a log says where it lives:
reading a log imports nothing the log names. A message whose type nobody declares is
"not installed": decoded as plain data, and checked only against the JSON Schema the log
embeds (:mod:`slamfront.mcaplog.validate`).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from slamfront.errors import LogError, PluginError
from slamfront.messages import SHARED_MESSAGES, Message, decode_any

FRAMEWORK = "slamfront (framework)"
"""The origin of the shared message types."""


@dataclass(frozen=True)
class MessageType:
    """A declared message class and the package that declares it."""

    cls: type[Message]
    origin: str
    """``slamfront 0.1.0``, ``slamfront-example-plugin 0.1.0``, ``local module my_plugins``."""


class MessageTypes:
    """Message classes by schema name.

    :param declared: ``(class, origin)`` pairs from plugin modules, after the shared types.
    :raises PluginError: a declared class is not a message type, or two packages declare
        one schema name (the message names both).
    """

    def __init__(self, declared: Iterable[tuple[type[Message], str]] = ()) -> None:
        self._types: dict[str, MessageType] = {}
        for cls in SHARED_MESSAGES:
            self.add(cls, FRAMEWORK)
        for cls, origin in declared:
            self.add(cls, origin)

    def add(self, cls: type[Message], origin: str) -> None:
        """Register one more type (the same class twice is fine)."""
        problem = _declaration_problem(cls)
        if problem:
            raise PluginError(f"{origin}: {problem}")
        known = self._types.get(cls.schema_name)
        if known is not None and known.cls is not cls:
            raise PluginError(
                f"two message types are named {cls.schema_name!r}: {known.cls.__qualname__} from {known.origin} "
                f"and {cls.__qualname__} from {origin}; schema names must be unique"
            )
        self._types[cls.schema_name] = MessageType(cls, origin)

    def __contains__(self, schema_name: object) -> bool:
        return schema_name in self._types

    def __iter__(self) -> Iterator[MessageType]:
        return iter(sorted(self._types.values(), key=lambda t: t.cls.schema_name))

    def __len__(self) -> int:
        return len(self._types)

    def get(self, schema_name: str) -> type[Message] | None:
        """The class of ``schema_name``, or None when no installed package declares it."""
        found = self._types.get(schema_name)
        return found.cls if found is not None else None

    def origin(self, schema_name: str) -> str:
        """Who declares ``schema_name`` ("" when nobody does)."""
        found = self._types.get(schema_name)
        return found.origin if found is not None else ""

    def require(self, schema_name: str, where: str = "") -> type[Message]:
        """The class of ``schema_name``.

        :raises LogError: not installed (naming ``where`` the log uses it).
        """
        cls = self.get(schema_name)
        if cls is None:
            at = f"{where}: " if where else ""
            raise LogError(
                f"{at}message type {schema_name!r} is not installed (no installed plugin package declares it "
                "with slamfront_message_types; install its package, or name its module with -p)"
            )
        return cls

    def decode(self, schema_name: str, data: bytes | str) -> Message | dict[str, Any]:
        """A JSON message as its class, or as a dict (arrays as NumPy arrays) when not installed."""
        cls = self.get(schema_name)
        return cls.from_json(data) if cls is not None else decode_any(data)

    def volatile_fields(self, schema_name: str) -> tuple[str, ...]:
        """The fields ``diff`` leaves out of ``schema_name`` (none for a type not installed)."""
        cls = self.get(schema_name)
        return cls.volatile_fields if cls is not None else ()


def _declaration_problem(cls: object) -> str | None:
    if not (inspect.isclass(cls) and issubclass(cls, Message)):
        return f"{cls!r} declared as a message type does not derive from slamfront.messages.Message"
    if "__dataclass_fields__" not in vars(cls):  # a subclass without @dataclass would encode its parent's fields
        return f"message type {cls.__qualname__} is not a dataclass"
    name = vars(cls).get("schema_name")
    if not isinstance(name, str) or not name or name == Message.schema_name:
        return f"message type {cls.__qualname__} has no schema_name of its own"
    return None


@functools.cache
def shared_message_types() -> MessageTypes:
    """The framework's own types only (no plugin is imported)."""
    return MessageTypes()


@functools.cache
def installed_message_types() -> MessageTypes:
    """The types of slamfront and of every installed plugin package (the ``slamfront``
    entry-point group), collected once per process, the first time a reader meets a JSON
    message that is not one of the shared types."""
    from slamfront.registry import PluginRegistry

    return PluginRegistry().message_types()


def types_for(schema_name: str, types: MessageTypes | None = None) -> MessageTypes:
    """``types``, or by default the shared types when they hold ``schema_name`` (no plugin
    is imported for them), else the installed ones."""
    if types is not None:
        return types
    shared = shared_message_types()
    return shared if schema_name in shared else installed_message_types()


def decode_json(schema_name: str, data: bytes | str, types: MessageTypes | None = None) -> Message | dict[str, Any]:
    """Decode a JSON message with ``types`` (default: :func:`types_for`)."""
    return types_for(schema_name, types).decode(schema_name, data)
