"""Writing a run's MCAP log.

Two encodings share one file: Foxglove's protobuf schemas for things Foxglove draws
(images, poses, transforms, clouds, markers, log lines) and slamfront's JSON messages
(:mod:`slamfront.messages`) for stage outputs. The writer is finalised on close, also
when the run ends with an exception, so the file always has its summary and footer.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from slamfront.errors import LogError
from slamfront.messages import Message

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

PROFILE = ""  # no ROS profile: Foxglove reads protobuf and jsonschema channels directly


class RunLogWriter:
    """An open MCAP file that stage outputs and Foxglove messages are written to.

    :param path: the ``.mcap`` file to create (overwritten if it exists).
    :param compression: ``zstd``, ``lz4`` or ``none`` (chunk compression).
    :param chunk_size: bytes per chunk; a crash loses at most the chunk being filled.
    :param library: written into the MCAP header.
    """

    def __init__(
        self, path: Path, compression: str = "zstd", chunk_size: int = 1 << 20, library: str = "slamfront"
    ) -> None:
        self.path = Path(path)
        try:
            self._stream: IO[bytes] = open(self.path, "wb")
        except OSError as exc:
            raise LogError(f"{self.path}: cannot create log: {exc.strerror or exc}") from exc
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._writer.start(profile=PROFILE, library=library)
        self._channels: dict[str, tuple[int, str]] = {}
        self._json_schemas: dict[str, int] = {}
        self._protobuf_schemas: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._closed = False
        self.bytes_payload = 0
        self.n_messages = 0

    # -- channels ------------------------------------------------------------------------

    def _json_channel(self, topic: str, cls: type[Message]) -> int:
        if cls.schema_name not in self._json_schemas:
            self._json_schemas[cls.schema_name] = self._writer.register_schema(
                name=cls.schema_name,
                encoding="jsonschema",
                data=json.dumps(cls.json_schema()).encode(),
            )
        return self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=self._json_schemas[cls.schema_name]
        )

    def _protobuf_channel(self, topic: str, message: Any) -> int:
        name = type(message).DESCRIPTOR.full_name
        if name not in self._protobuf_schemas:
            self._protobuf_schemas[name] = register_schema(self._writer, type(message))
        schema_id = self._protobuf_schemas[name]
        return self._writer.register_channel(topic=topic, message_encoding="protobuf", schema_id=schema_id)

    def _channel_for(self, topic: str, schema_name: str, make: Any) -> int:
        known = self._channels.get(topic)
        if known is None:
            channel_id = make()
            self._channels[topic] = (channel_id, schema_name)
            return channel_id
        channel_id, known_schema = known
        if known_schema != schema_name:
            raise LogError(f"{self.path}: topic {topic} carries {known_schema}, cannot write {schema_name} to it")
        return channel_id

    # -- writing -------------------------------------------------------------------------

    def _add(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        if self._closed:
            raise LogError(f"{self.path}: the log is already closed")
        sequence = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = sequence + 1
        self._writer.add_message(
            channel_id=channel_id, log_time=log_time_ns, publish_time=log_time_ns, data=data, sequence=sequence
        )
        self.bytes_payload += len(data)
        self.n_messages += 1

    def write(self, topic: str, message: Message, log_time_ns: int) -> None:
        """Write a slamfront message (JSON) on ``topic``."""
        channel = self._channel_for(topic, message.schema_name, lambda: self._json_channel(topic, type(message)))
        self._add(channel, log_time_ns, message.to_json())

    def write_foxglove(self, topic: str, message: Any, log_time_ns: int) -> None:
        """Write a protobuf message (a Foxglove schema) on ``topic``."""
        name = type(message).DESCRIPTOR.full_name
        channel = self._channel_for(topic, name, lambda: self._protobuf_channel(topic, message))
        self._add(channel, log_time_ns, message.SerializeToString())

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record (string key/values), e.g. the run's versions."""
        self._writer.add_metadata(name, {k: str(v) for k, v in values.items()})

    def add_attachment(self, name: str, media_type: str, data: bytes) -> None:
        """A file stored inside the log, e.g. the resolved recipe."""
        now = time.time_ns()
        self._writer.add_attachment(create_time=now, log_time=now, name=name, media_type=media_type, data=data)

    # -- lifetime ------------------------------------------------------------------------

    def close(self) -> None:
        """Write the summary and footer and close the file. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
