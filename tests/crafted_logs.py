"""Crafted logs: well-formed MCAP files (every CRC, index and summary right) whose
messages were dropped, duplicated, reordered or re-encoded after the run wrote them.

A copy keeps each message's sequence number, as a tool moving records around would;
the tests and ``benchmarks/bench_log_fuzz.py`` check that slamfront names the change.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from mcap.records import Attachment, Header, Message, Metadata
from mcap.writer import CompressionType, Writer

from tests.helpers import scanned_records


@dataclass(frozen=True)
class Entry:
    """One message as stored, with its channel's description."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    encoding: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass
class LogContent:
    library: str
    messages: list[Entry]
    metadata: list[tuple[str, dict[str, str]]]
    attachments: list[tuple[str, str, int, bytes]]


def read_content(path: Path) -> LogContent:
    """Every record of an undamaged log, in file order."""
    content = LogContent("", [], [], [])
    for record, channel, schema in scanned_records(path):
        if isinstance(record, Header):
            content.library = record.library
        elif isinstance(record, Message):
            content.messages.append(Entry(
                channel.topic, schema.name, schema.encoding, bytes(schema.data), channel.message_encoding,
                record.log_time, record.publish_time, record.sequence, bytes(record.data)))
        elif isinstance(record, Metadata):
            content.metadata.append((record.name, dict(record.metadata)))
        elif isinstance(record, Attachment):
            content.attachments.append((record.name, record.media_type, record.log_time, bytes(record.data)))
    return content


def write_content(content: LogContent, target: Path, compression: str = "zstd") -> Path:
    """A finalised MCAP file holding ``content`` exactly (sequence numbers included)."""
    kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    with open(target, "wb") as stream:
        writer = Writer(stream, chunk_size=1 << 16, compression=kinds[compression], enable_data_crcs=True)
        writer.start(profile="", library=content.library)
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        channel_ids: dict[tuple[str, str, int], int] = {}
        for entry in content.messages:
            key = (entry.schema_name, entry.schema_encoding, entry.schema_data)
            if key not in schema_ids:
                schema_ids[key] = writer.register_schema(entry.schema_name, entry.schema_encoding, entry.schema_data)
            channel = (entry.topic, entry.encoding, schema_ids[key])
            if channel not in channel_ids:
                channel_ids[channel] = writer.register_channel(entry.topic, entry.encoding, schema_ids[key])
            writer.add_message(channel_ids[channel], entry.log_time, entry.data, entry.publish_time, entry.sequence)
        for name, values in content.metadata:
            writer.add_metadata(name, values)
        for name, media_type, log_time, data in content.attachments:
            writer.add_attachment(log_time, log_time, name, media_type, data)
        writer.finish()
    return target


def craft(source: Path, target: Path, change: Callable[[list[Entry]], list[Entry]]) -> Path:
    """A copy of ``source`` whose message list is ``change(messages)``."""
    content = read_content(source)
    content.messages = change(content.messages)
    return write_content(content, target)


def with_encoding(prefix: str, encoding: str) -> Callable[[list[Entry]], list[Entry]]:
    """Every topic starting with ``prefix`` declared in ``encoding`` (its bytes unchanged)."""
    return lambda messages: [replace(m, encoding=encoding) if m.topic.startswith(prefix) else m for m in messages]


def repeated(topic: str, times: int, renumber: bool = True) -> Callable[[list[Entry]], list[Entry]]:
    """Each ``topic`` message written ``times`` times (numbered on, as a writer fed the
    same message again would, unless ``renumber`` is False)."""

    def change(messages: list[Entry]) -> list[Entry]:
        out: list[Entry] = []
        count = 0
        for message in messages:
            copies = times if message.topic == topic else 1
            for _ in range(copies):
                if message.topic == topic and renumber:
                    message = replace(message, sequence=count)
                    count += 1
                out.append(message)
        return out

    return change


def swapped(topic: str, first: int, renumber: bool = True) -> Callable[[list[Entry]], list[Entry]]:
    """Messages ``first`` and ``first + 1`` of ``topic`` trade places (and numbers, if ``renumber``)."""

    def change(messages: list[Entry]) -> list[Entry]:
        positions = [i for i, m in enumerate(messages) if m.topic == topic]
        a, b = positions[first], positions[first + 1]
        out = list(messages)
        out[a], out[b] = messages[b], messages[a]
        if renumber:
            out[a], out[b] = replace(out[a], sequence=messages[a].sequence), replace(out[b], sequence=messages[b].sequence)
        return out

    return change


def dropped(topic: str, index: int) -> Callable[[list[Entry]], list[Entry]]:
    """Message ``index`` of ``topic`` left out (the others keep their numbers)."""

    def change(messages: list[Entry]) -> list[Entry]:
        position = [i for i, m in enumerate(messages) if m.topic == topic][index]
        return messages[:position] + messages[position + 1 :]

    return change
