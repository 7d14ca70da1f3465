"""Checking that a log is one Foxglove and other MCAP readers understand.

Each topic must carry either a Foxglove schema (``protobuf``, a ``foxglove.*`` message
of ``foxglove-schemas-protobuf``) or a registered slamfront schema (``jsonschema`` +
``json``, a :class:`~slamfront.messages.Message` subclass that is imported). Every
message is decoded: protobuf messages must parse, JSON messages must decode to their
class and encode back to the same bytes (bit-exact round trip). Foxglove messages'
``timestamp`` must equal their log time and their ``frame_id`` must not be empty, so
panels line them up in time and the 3-D panel can place them.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import foxglove_schemas_protobuf
from google.protobuf.message import DecodeError

from slamfront.errors import LogError
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.messages import message_class
from slamfront.text import shorten


@cache
def foxglove_message_types() -> dict[str, Any]:
    """``foxglove.<Name>`` -> protobuf class, for every schema Foxglove defines."""
    types = {}
    for module in pkgutil.iter_modules(foxglove_schemas_protobuf.__path__):
        if module.name.endswith("_pb2"):
            loaded = importlib.import_module(f"{foxglove_schemas_protobuf.__name__}.{module.name}")
            for name, descriptor in loaded.DESCRIPTOR.message_types_by_name.items():
                types[descriptor.full_name] = getattr(loaded, name)
    return types


@dataclass
class Validation:
    """What :func:`validate_log` found; ``problems`` is empty for a valid log."""

    path: Path
    n_messages: int = 0
    n_topics: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def valid(self) -> bool:
        return not self.problems


def validate_log(path: Path, max_problems: int = 20) -> Validation:
    """Check every topic's schema and decode every message of ``path``."""
    path = Path(path)
    result = Validation(path)
    summary = summarize(path)
    if not summary.complete:
        result.problems.append(f"the log is not finalised: {summary.problem}")
    foxglove = foxglove_message_types()
    decoders: dict[str, Any] = {}
    for topic in summary.topics:
        result.n_topics += 1
        kind = (topic.schema_encoding, topic.message_encoding)
        if kind == ("protobuf", "protobuf") and topic.schema_name in foxglove:
            decoders[topic.topic] = foxglove[topic.schema_name]
        elif kind == ("jsonschema", "json"):
            try:
                decoders[topic.topic] = message_class(topic.schema_name)
            except LogError as exc:
                result.problems.append(f"{topic.topic}: {exc}")
        else:
            result.problems.append(
                f"{topic.topic}: schema {topic.schema_name!r} ({topic.schema_encoding}/{topic.message_encoding}) "
                "is neither a Foxglove schema nor a registered slamfront one"
            )
    try:
        for message in read_messages(path):
            result.n_messages += 1
            decoder = decoders.get(message.topic)
            if decoder is None or len(result.problems) >= max_problems:
                continue
            problem = _check(message, decoder)
            if problem:
                result.problems.append(f"{message.topic} message at {message.log_time_ns} ns: {problem}")
    except LogError as exc:
        result.problems.append(str(exc))
    return result


def _check(message: Any, decoder: Any) -> str | None:
    if message.message_encoding == "json":
        try:
            decoded = decoder.from_json(message.data)
        except (ValueError, TypeError, KeyError, IndexError, AttributeError, RecursionError) as exc:
            return f"does not decode as {decoder.schema_name}: {type(exc).__name__}: {shorten(str(exc), 160)}"
        if decoded.to_json() != message.data:
            return f"does not round-trip bit-exactly through {decoder.schema_name}"
        return None
    try:
        decoded = decoder.FromString(message.data)
    except DecodeError as exc:
        return f"does not parse as {decoder.DESCRIPTOR.full_name}: {exc}"
    return _stamped(decoded, message.log_time_ns)


_NESTED = ("transforms", "entities")  # FrameTransforms, SceneUpdate: each item is stamped and framed
_FRAME_FIELDS = ("frame_id", "parent_frame_id", "child_frame_id")


def _stamped(decoded: Any, log_time_ns: int) -> str | None:
    fields = decoded.DESCRIPTOR.fields_by_name
    if "timestamp" in fields and decoded.timestamp.ToNanoseconds() != log_time_ns:
        return f"timestamp {decoded.timestamp.ToNanoseconds()} ns differs from its log time"
    for name in _FRAME_FIELDS:
        if name in fields and not getattr(decoded, name):
            return f"empty {name}"
    for name in _NESTED:
        if name in fields:
            for item in getattr(decoded, name):
                problem = _stamped(item, log_time_ns)
                if problem:
                    return f"{name}: {problem}"
    return None
