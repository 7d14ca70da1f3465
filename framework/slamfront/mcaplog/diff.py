"""Comparing two logs message by message: ``slamfront diff LOG_A LOG_B``.

Messages are compared per topic, in the order they were written: the k-th message of a
topic in A against the k-th in B, bytes and log time. For each topic that differs, the
first differing message is decoded and the first differing field named
(``vector[12]``, ``candidates``, ``pose.position.x``, ...).

What measures the machine rather than the method is left out by default, so two runs of
one recipe compare equal: the ``/log`` topic (human-readable lines with durations) and,
in ``RunMetrics`` and ``StageStatistics`` messages, the keys that are timings or memory
(:data:`VOLATILE_KEY`), and in other messages the fields their class declares
``volatile_fields`` (per-frame wall times; known for the installed message types,
:mod:`slamfront.message_types`, none for a type no installed package declares).
``strict`` compares everything.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from google.protobuf.json_format import MessageToDict

from slamfront.mcaplog.reader import LoggedMessage, read_messages
from slamfront.message_types import types_for
from slamfront.messages import RunMetrics, StageStatistics, decode_any

if TYPE_CHECKING:
    from slamfront.message_types import MessageTypes

DEFAULT_IGNORED_TOPICS = ("/log",)
VOLATILE_KEY = re.compile(r"^(timing|frames_per_second)$|^log_|seconds|_ms(_|$)|_s$|per_second|rss|memory")
"""Keys of run metrics and stage statistics that are wall times, rates or memory."""
_VOLATILE_SCHEMAS = (RunMetrics.schema_name, StageStatistics.schema_name)
_UNDECODABLE = (ValueError, TypeError, KeyError, AttributeError, RecursionError)
"""What decoding a damaged or crafted JSON message raises; ``diff`` then compares bytes."""


@dataclass(frozen=True)
class TopicDifference:
    """The first difference on one topic."""

    topic: str
    index: int
    """0-based position of the message within its topic."""
    field: str
    """The first differing field, or what differs about the topic in parentheses."""
    a: str = ""
    b: str = ""
    log_time_ns: int | None = None

    def describe(self) -> str:
        when = f" (log time {self.log_time_ns / 1e9:.6f} s)" if self.log_time_ns is not None else ""
        values = f": {self.a} vs {self.b}" if self.a or self.b else ""
        return f"{self.topic}  message {self.index}{when}  {self.field}{values}"


@dataclass
class LogDiff:
    """The outcome of :func:`diff_logs`."""

    differences: list[TopicDifference] = field(default_factory=list)
    topics_compared: int = 0
    messages_compared: int = 0
    ignored: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return not self.differences


@dataclass
class _Entry:
    log_time: int
    digest: bytes
    schema: str


def _volatile_fields(schema_name: str, types: MessageTypes | None) -> tuple[str, ...]:
    return types_for(schema_name, types).volatile_fields(schema_name)


def _without_volatile(decoded: dict[str, Any], schema_name: str, types: MessageTypes | None) -> dict[str, Any]:
    """The decoded JSON message without what measures the machine."""
    if schema_name in _VOLATILE_SCHEMAS and isinstance(decoded.get("values"), dict):
        decoded["values"] = {k: v for k, v in decoded["values"].items() if not VOLATILE_KEY.search(k)}
    for name in _volatile_fields(schema_name, types):
        decoded.pop(name, None)
    return decoded


def comparable_bytes(message: LoggedMessage, strict: bool = False, types: MessageTypes | None = None) -> bytes:
    """The bytes ``diff`` compares: the message's own, or, unless ``strict``, its JSON
    without the keys and fields that measure the machine.

    :param types: the message types that know volatile fields (default: the installed ones).
    """
    if strict or message.message_encoding != "json":
        return message.data
    if message.schema_name not in _VOLATILE_SCHEMAS and not _volatile_fields(message.schema_name, types):
        return message.data
    try:
        decoded = json.loads(message.data)
    except _UNDECODABLE:
        return message.data  # not JSON after all (damaged or crafted): compare its bytes
    if not isinstance(decoded, dict):
        return message.data
    return json.dumps(_without_volatile(decoded, message.schema_name, types), sort_keys=True).encode()


def _index(path: Path, ignored: Sequence[str], strict: bool, types: MessageTypes | None) -> dict[str, list[_Entry]]:
    topics: dict[str, list[_Entry]] = {}
    for message in read_messages(path, strict=False, types=types):
        if _is_ignored(message.topic, ignored):
            continue
        digest = hashlib.blake2b(comparable_bytes(message, strict, types), digest_size=16).digest()
        topics.setdefault(message.topic, []).append(_Entry(message.log_time_ns, digest, message.schema_name))
    return topics


def _is_ignored(topic: str, ignored: Sequence[str]) -> bool:
    return any(fnmatch.fnmatchcase(topic, pattern) for pattern in ignored)


def diff_logs(
    a: Path, b: Path, ignore: Sequence[str] = (), strict: bool = False, types: MessageTypes | None = None
) -> LogDiff:
    """The first differing message of every topic of two logs.

    :param ignore: topic patterns (shell globs) to leave out, besides the defaults.
    :param strict: compare everything, timings and ``/log`` included.
    :param types: the message types that know volatile fields (default: the installed ones).
    """
    ignored = [*([] if strict else DEFAULT_IGNORED_TOPICS), *ignore]
    index_a, index_b = _index(Path(a), ignored, strict, types), _index(Path(b), ignored, strict, types)
    result = LogDiff(ignored=ignored)
    wanted: dict[str, int] = {}
    for topic in sorted(set(index_a) | set(index_b)):
        entries_a, entries_b = index_a.get(topic, []), index_b.get(topic, [])
        result.topics_compared += 1
        result.messages_compared += min(len(entries_a), len(entries_b))
        if not entries_b or not entries_a:
            side = "A" if entries_a else "B"
            count = len(entries_a or entries_b)
            result.differences.append(TopicDifference(topic, 0, f"(topic only in {side}, {count} messages)"))
            continue
        if entries_a[0].schema != entries_b[0].schema:
            result.differences.append(TopicDifference(topic, 0, "(schema)", entries_a[0].schema, entries_b[0].schema))
            continue
        for position, (x, y) in enumerate(zip(entries_a, entries_b)):
            if x.digest != y.digest:
                wanted[topic] = position
                break
            if x.log_time != y.log_time:
                result.differences.append(
                    TopicDifference(topic, position, "(log time)", str(x.log_time), str(y.log_time), x.log_time)
                )
                break
        else:
            if len(entries_a) != len(entries_b):
                result.differences.append(
                    TopicDifference(
                        topic, min(len(entries_a), len(entries_b)),
                        f"(message count: A has {len(entries_a)}, B has {len(entries_b)})",
                    )
                )
    if wanted:
        messages_a = _fetch(Path(a), wanted, types)
        messages_b = _fetch(Path(b), wanted, types)
        for topic, position in wanted.items():
            first = _first_field(
                _comparable(messages_a[topic], strict, types), _comparable(messages_b[topic], strict, types)
            )
            path, value_a, value_b = first or ("(bytes)", "", "")
            result.differences.append(
                TopicDifference(topic, position, path or "(whole message)", value_a, value_b,
                                messages_a[topic].log_time_ns)
            )
    result.differences.sort(key=lambda d: d.topic)
    return result


def _fetch(path: Path, wanted: dict[str, int], types: MessageTypes | None) -> dict[str, LoggedMessage]:
    counts: dict[str, int] = {}
    found: dict[str, LoggedMessage] = {}
    for message in read_messages(path, list(wanted), strict=False, types=types):
        position = counts.get(message.topic, 0)
        counts[message.topic] = position + 1
        if position == wanted[message.topic]:
            found[message.topic] = message
            if len(found) == len(wanted):
                break
    return found


def _comparable(message: LoggedMessage, strict: bool, types: MessageTypes | None) -> Any:
    """A message as nested dicts, lists and arrays."""
    if message.message_encoding == "json":
        try:
            decoded = decode_any(message.data)
        except _UNDECODABLE:
            return {"(bytes)": message.data}
        return decoded if strict else _without_volatile(decoded, message.schema_name, types)
    try:
        return MessageToDict(message.decoded, preserving_proto_field_name=True)
    except Exception:  # noqa: BLE001 (undecodable: compare the raw bytes)
        return {"(bytes)": message.data}


def _first_field(a: Any, b: Any, path: str = "") -> tuple[str, str, str] | None:
    """(path, value in A, value in B) of the first difference, or None when equal."""
    for where, x, y in _walk(a, b, path):
        return where, _show(x), _show(y)
    return None


def _walk(a: Any, b: Any, path: str) -> Iterator[tuple[str, Any, Any]]:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in [*a, *(k for k in b if k not in a)]:
            child = f"{path}.{key}" if path else str(key)
            if key not in a or key not in b:
                yield child, a.get(key, "(absent)"), b.get(key, "(absent)")
                return
            yield from _walk(a[key], b[key], child)
        return
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        if a.dtype != b.dtype or a.shape != b.shape:
            yield f"{path} (dtype/shape)", f"{a.dtype}{list(a.shape)}", f"{b.dtype}{list(b.shape)}"
            return
        if a.tobytes() != b.tobytes():
            flat_a = np.ascontiguousarray(a).view(np.uint8).reshape(a.size, -1)
            flat_b = np.ascontiguousarray(b).view(np.uint8).reshape(b.size, -1)
            first = int(np.flatnonzero(np.any(flat_a != flat_b, axis=1))[0])
            where = np.unravel_index(first, a.shape)
            yield f"{path}[{', '.join(str(int(i)) for i in where)}]", a[where], b[where]
        return
    if isinstance(a, list) and isinstance(b, list):
        for k, (x, y) in enumerate(zip(a, b)):
            yield from _walk(x, y, f"{path}[{k}]")
        if len(a) != len(b):
            yield f"{path} (length)", len(a), len(b)
        return
    if type(a) is not type(b) or a != b:
        if not (isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b)):
            yield path, a, b


def _show(value: Any) -> str:
    text = repr(value.item() if isinstance(value, np.generic) else value)
    return text if len(text) <= 80 else text[:77] + "..."
