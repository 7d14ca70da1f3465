"""Small builders shared by the tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Message, Metadata, Schema

from slamfront.mcaplog.diff import comparable_bytes
from slamfront.mcaplog.reader import read_messages
from slamfront.mcaplog.scan import RecordScanner
from slamfront.mcaplog.writer import RunLogWriter


def small_synthetic_recipe(**source_params: Any) -> dict[str, Any]:
    """A recipe dict for a quick synthetic run (few, small frames)."""
    params = {"frames_per_traversal": 40, "route_length_m": 80, "image_width": 64, "image_height": 48}
    params.update(source_params)
    return {
        "name": "small",
        "source": {"plugin": "synthetic", "params": params},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {}},
        "eval": {"plots": False},
    }


def rewrite_log(
    source: Path, target: Path, change: Callable[[str, int, bytes], bytes | None] = lambda _t, _i, data: data,
    attachment: Callable[[str, bytes], bytes] = lambda _name, data: data,
) -> None:
    """Copy a log record by record; ``change(topic, index in topic, data)`` may alter a
    message (return new bytes) or drop it (return None); ``attachment(name, data)`` may
    alter an attachment. Metadata are kept."""
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    counts: dict[str, int] = {}
    with open(source, "rb") as stream, RunLogWriter(target, chunk_size=1 << 16) as log:
        for record in RecordScanner(stream, source.stat().st_size).records():
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                schema = schemas[channel.schema_id]
                index = counts.get(channel.topic, 0)
                counts[channel.topic] = index + 1
                data = change(channel.topic, index, bytes(record.data))
                if data is not None:
                    log.write_raw(channel.topic, schema.name, schema.encoding, bytes(schema.data),
                                  channel.message_encoding, data, record.log_time, record.publish_time)
            elif isinstance(record, Metadata):
                log.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Attachment):
                log.add_attachment(record.name, record.media_type, attachment(record.name, bytes(record.data)),
                                   record.log_time)


def stage_topic_bytes(path: Path, prefix: str) -> dict[str, list[bytes]]:
    """Every message's bytes on the topics starting with ``prefix``, by topic, as
    ``slamfront diff`` compares them (wall-time fields left out)."""
    topics: dict[str, list[bytes]] = {}
    for message in read_messages(path):
        if message.topic.startswith(prefix):
            topics.setdefault(message.topic, []).append(comparable_bytes(message))
    return topics
