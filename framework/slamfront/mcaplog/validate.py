"""Checking that a log is one Foxglove and other MCAP readers understand.

Each topic must carry either a Foxglove schema (``protobuf``, a ``foxglove.*`` message
of ``foxglove-schemas-protobuf``) or a JSON one (``jsonschema`` + ``json``). Every
message is decoded: protobuf messages must parse; JSON messages of an installed type
(:mod:`slamfront.message_types`: slamfront's own and those installed plugins declare)
must decode to their class and encode back to the same bytes (bit-exact round trip).
A JSON message whose type no installed package declares is checked against the JSON
Schema the log embeds for it and reported as *not installed*, which is not a fault of
the log. Foxglove messages' ``timestamp`` must equal their log time and their
``frame_id`` must not be empty, so panels line them up in time and the 3-D panel can
place them.

An embedded schema is data from the log: it is evaluated with the structural keywords
only (types, properties, items, enums, combinations, bounds, local ``$ref``); nothing is
fetched and no regular expression from the log is run.

Two more checks catch a log that was changed after it was written, even when every
CRC was recomputed: a channel slamfront would not have written (a message encoding it
cannot read, or a schema that is not the one it writes on that topic:
:func:`channel_problem`), and messages duplicated, reordered or dropped (:class:`OrderCheck`: slamfront's writer
numbers each channel's messages 0, 1, 2, ..., and every frame has one ``/frames``
message, in order). ``replay`` refuses such a log with the same one-line message.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import re
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import foxglove_schemas_protobuf
from google.protobuf.message import DecodeError

from slamfront.errors import LogError
from slamfront.mcaplog.reader import (
    LoggedMessage,
    TopicSummary,
    read_messages,
    read_messages_and_gaps,
    summarize,
    writer_library,
)
from slamfront.mcaplog.topics import (
    CALIBRATION_TOPIC,
    DEPTH_TOPIC,
    EVENTS_TOPIC,
    FRAMES_TOPIC,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    LOG_TOPIC,
    LOOP_TRUTH_TOPIC,
    METRICS_TOPIC,
    POINTS_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    stage_of,
)
from slamfront.message_types import MessageTypes, installed_message_types
from slamfront.text import shorten

MAX_SCHEMA_BYTES = 1 << 20
"""Largest embedded JSON Schema evaluated (slamfront's own are a few KiB)."""
_STRUCTURAL_KEYWORDS = (
    "$ref", "additionalProperties", "allOf", "anyOf", "const", "contains", "dependentRequired", "enum",
    "exclusiveMaximum", "exclusiveMinimum", "items", "maxItems", "maxLength", "maxProperties", "maximum",
    "minItems", "minLength", "minProperties", "minimum", "not", "oneOf", "prefixItems", "properties",
    "propertyNames", "required", "type",
)
"""What an embedded schema is checked with: no ``pattern`` (a crafted regular expression
could run for hours), no ``format``, no ``uniqueItems`` (quadratic)."""


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


READABLE_ENCODINGS = ("json", "protobuf")
"""Message encodings slamfront decodes; a channel in any other is named, never skipped."""

_SCHEMA_ENCODING = {"json": "jsonschema", "protobuf": "protobuf"}
_FIXED_TOPICS = {
    FRAMES_TOPIC: "slamfront.FrameInfo", EVENTS_TOPIC: "slamfront.RunEvent", METRICS_TOPIC: "slamfront.RunMetrics",
    LOOP_TRUTH_TOPIC: "slamfront.LoopTruth", IMAGE_TOPIC: "foxglove.CompressedImage",
    DEPTH_TOPIC: "foxglove.RawImage", CALIBRATION_TOPIC: "foxglove.CameraCalibration",
    POINTS_TOPIC: "foxglove.PointCloud", GROUND_TRUTH_TOPIC: "foxglove.PoseInFrame", TF_TOPIC: "foxglove.FrameTransforms",
    LOG_TOPIC: "foxglove.Log", SCENE_TOPIC: "foxglove.SceneUpdate",
}
"""The schema slamfront writes on each of its frame and run topics."""


def channel_problem(topic: TopicSummary) -> str | None:
    """Why ``topic`` is not a channel slamfront wrote, or None: its message encoding is one
    slamfront cannot read, does not go with its schema's encoding, or its schema is not
    the one slamfront writes there (a stage's JSON messages go on ``/<stage>/<type in
    snake_case>``, :func:`~slamfront.mcaplog.topics.topic_for`)."""
    encoding, name = topic.message_encoding, topic.schema_name
    if encoding not in READABLE_ENCODINGS:
        return (
            f"{topic.topic}: message encoding {encoding!r} is not one slamfront reads "
            f"({' or '.join(READABLE_ENCODINGS)}): its messages cannot be decoded"
        )
    if topic.schema_encoding != _SCHEMA_ENCODING[encoding]:
        return f"{topic.topic}: {encoding} messages with a {topic.schema_encoding or 'missing'!r} schema cannot be decoded"
    expected = _FIXED_TOPICS.get(topic.topic)
    if expected is None and encoding == "json" and stage_of(topic.topic) is not None:
        snake = re.sub(r"(?<!^)(?=[A-Z])", "_", name.rpartition(".")[2]).lower()
        if topic.topic != f"/{stage_of(topic.topic)}/{snake}":
            return f"{topic.topic}: carries {name!r} messages, which slamfront writes on /{stage_of(topic.topic)}/{snake}"
    elif expected is not None and name != expected:
        return f"{topic.topic}: carries {name!r} messages where slamfront writes {expected!r}"
    return None


def check_channels(path: Path, topics: list[TopicSummary]) -> None:
    """:raises LogError: a topic of ``path`` is not one slamfront wrote (:func:`channel_problem`)."""
    for topic in topics:
        problem = channel_problem(topic)
        if problem:
            raise LogError(f"{path}: {problem}; the log was changed after it was written")


class OrderCheck:
    """Messages of one log in the order they are read: on each channel of a log slamfront
    wrote, sequence numbers 0, 1, 2, ... (a duplicated, reordered or lost record breaks
    the count), and one ``/frames`` message per frame, frame indices increasing.

    :param numbered: check sequence numbers (a slamfront log: :func:`numbered_log`).
    :param gaps: accept missing sequence numbers (a damaged log read with ``--salvage``,
        whose damage is reported on its own).
    """

    def __init__(self, numbered: bool, gaps: bool = False) -> None:
        self._numbered = numbered
        self._gaps = gaps
        self._next: dict[str, int] = {}
        self._last_frame: int | None = None

    def problem(self, message: LoggedMessage) -> str | None:
        """What is wrong with ``message`` coming next, or None."""
        where = f"{message.topic} message at {message.log_time_ns} ns"
        if self._numbered:
            expected = self._next.get(message.topic, 0)
            self._next[message.topic] = max(expected, message.sequence + 1)
            if message.sequence < expected:
                return (
                    f"{where}: sequence number {message.sequence} where {expected} was expected: a duplicated or "
                    "reordered message"
                )
            if message.sequence > expected and not self._gaps:
                lost = message.sequence - expected
                return (
                    f"{where}: sequence number {message.sequence} where {expected} was expected: {lost} "
                    f"message{'s' * (lost > 1)} missing (or moved)"
                )
        if message.topic == FRAMES_TOPIC:
            try:
                frame = int(message.decoded.frame)
            except (LogError, AttributeError, TypeError, ValueError):
                return None  # a message that does not decode is reported as such
            last, self._last_frame = self._last_frame, frame if self._last_frame is None else max(frame, self._last_frame)
            if last is not None and frame <= last:
                kind = "a duplicated frame message" if frame == last else "frame messages out of order"
                return f"{where}: frame {frame} after frame {last} ({kind})"
        return None

    def check(self, path: Path, message: LoggedMessage) -> None:
        """:raises LogError: naming ``path`` and what is wrong with ``message`` coming next."""
        problem = self.problem(message)
        if problem:
            raise LogError(
                f"{path}: {problem}; the log was changed after it was written "
                "(`slamfront inspect --validate` lists every problem)"
            )


def check_messages(path: Path, salvage: bool = False) -> None:
    """Read every message of ``path`` once (decoding only ``/frames``) and stop at the first
    sign that it was changed after it was written (:class:`OrderCheck`), before anything
    is done with it: a message missing for one frame is seen only when the next message
    of its channel arrives, after that frame would have been used.

    :param salvage: a damaged log read as far as it can be: gaps (what the damage took) pass.
    :raises LogError: a duplicated, reordered or missing message; or damage the summary
        did not show (when not ``salvage``).
    """
    order = OrderCheck(numbered_log(path), gaps=salvage)
    for message in read_messages_and_gaps(path, strict=not salvage):
        if message is not None:
            order.check(path, message)


def numbered_log(path: Path) -> bool:
    """``path`` was written by slamfront, whose writers number every channel's messages."""
    return writer_library(path).startswith("slamfront")


@dataclass
class Validation:
    """What :func:`validate_log` found; ``problems`` is empty for a valid log."""

    path: Path
    n_messages: int = 0
    n_topics: int = 0
    problems: list[str] = field(default_factory=list)
    not_installed: dict[str, str] = field(default_factory=dict)
    """Topic -> schema name of the JSON topics whose type no installed package declares
    (checked against the log's embedded schema instead)."""

    @property
    def valid(self) -> bool:
        return not self.problems


def validate_log(path: Path, max_problems: int = 20, types: MessageTypes | None = None) -> Validation:
    """Check every topic's schema and decode every message of ``path``.

    :param types: the message types to decode with (default: the installed ones).
    """
    path = Path(path)
    result = Validation(path)
    summary = summarize(path)
    if not summary.complete:
        result.problems.append(f"the log is not finalised: {summary.problem}")
    foxglove = foxglove_message_types()
    decoders: dict[str, Any] = {}
    json_topics = [t for t in summary.topics if (t.schema_encoding, t.message_encoding) == ("jsonschema", "json")]
    if types is None and json_topics:
        types = installed_message_types()
    for topic in summary.topics:
        result.n_topics += 1
        kind = (topic.schema_encoding, topic.message_encoding)
        unreadable = channel_problem(topic)
        if unreadable:
            result.problems.append(unreadable)
        elif kind == ("protobuf", "protobuf") and topic.schema_name in foxglove:
            decoders[topic.topic] = foxglove[topic.schema_name]
        elif kind == ("jsonschema", "json"):
            assert types is not None
            cls = types.get(topic.schema_name)
            if cls is not None:
                decoders[topic.topic] = cls
            else:
                result.not_installed[topic.topic] = topic.schema_name
        else:
            result.problems.append(
                f"{topic.topic}: schema {topic.schema_name!r} ({topic.schema_encoding}/{topic.message_encoding}) "
                "is neither a Foxglove schema nor a JSON one"
            )
    order = OrderCheck(numbered_log(path))
    embedded: dict[bytes, EmbeddedSchema] = {}
    try:
        for message in read_messages(path, types=types):
            result.n_messages += 1
            if len(result.problems) >= max_problems:
                continue
            decoder = decoders.get(message.topic)
            if decoder is None and message.topic in result.not_installed:
                decoder = embedded.get(message.schema_data)
                if decoder is None:
                    decoder = embedded[message.schema_data] = EmbeddedSchema(message.schema_name, message.schema_data)
            problem = order.problem(message)
            if problem:
                result.problems.append(problem)
            if decoder is None:
                continue
            problem = _check(message, decoder)
            if problem:
                result.problems.append(f"{message.topic} message at {message.log_time_ns} ns: {problem}")
    except LogError as exc:
        result.problems.append(str(exc))
    return result


class EmbeddedSchema:
    """The JSON Schema a log embeds for a message type that is not installed, checked
    with :data:`_STRUCTURAL_KEYWORDS` only and never fetching a ``$ref``."""

    def __init__(self, schema_name: str, data: bytes) -> None:
        self.schema_name = schema_name
        self.problem: str | None = None
        self._validator: Any = None
        if len(data) > MAX_SCHEMA_BYTES:
            self.problem = f"its embedded schema is {len(data)} bytes (more than {MAX_SCHEMA_BYTES} are not read)"
            return
        try:
            schema = json.loads(data)
        except (ValueError, RecursionError) as exc:
            self.problem = f"its embedded schema is not JSON: {shorten(str(exc), 120)}"
            return
        if not isinstance(schema, (dict, bool)):
            self.problem = "its embedded schema is not a JSON Schema (neither an object nor a boolean)"
            return
        self._validator = _structural_validator()(schema, registry=_no_retrieval())

    def check(self, data: bytes) -> str | None:
        """Why ``data`` does not match the schema, or None when it does."""
        if self.problem:
            return self.problem
        from jsonschema.exceptions import SchemaError
        from referencing.exceptions import Unresolvable

        try:
            instance = json.loads(data)
            error = next(iter(self._validator.iter_errors(instance)), None)
        except (ValueError, RecursionError) as exc:
            return f"is not JSON: {shorten(str(exc), 120)}"
        except (SchemaError, Unresolvable, TypeError, KeyError, AttributeError) as exc:
            return f"its embedded schema cannot be evaluated: {type(exc).__name__}: {shorten(str(exc), 120)}"
        if error is None:
            return None
        where = "/".join(str(p) for p in error.absolute_path) or "(the message)"
        return f"does not match the schema the log embeds for {self.schema_name}: at {where}: {shorten(error.message, 160)}"


@cache
def _structural_validator() -> Any:
    from jsonschema import Draft202012Validator, validators

    return validators.create(
        meta_schema=Draft202012Validator.META_SCHEMA,
        validators={k: v for k, v in Draft202012Validator.VALIDATORS.items() if k in _STRUCTURAL_KEYWORDS},
        type_checker=Draft202012Validator.TYPE_CHECKER,
        id_of=Draft202012Validator.ID_OF,
    )


def _no_retrieval() -> Any:
    """A reference registry that knows no other document (a remote ``$ref`` is unresolvable)."""
    from referencing import Registry

    return Registry()


def _check(message: Any, decoder: Any) -> str | None:
    if isinstance(decoder, EmbeddedSchema):
        return decoder.check(message.data)
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
