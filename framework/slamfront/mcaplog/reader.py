"""Reading run logs, including truncated ones.

A complete log is summarised from its summary section; a log without one (a run killed
by power loss) is scanned record by record up to the first incomplete record, and the
summary says what was lost.
"""

from __future__ import annotations

import io
import os
import stat
import struct
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, DataEnd, Header, Message, Metadata, Schema
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

from slamfront.errors import LogError
from slamfront.mcaplog.scan import MAGIC, RecordScanner, ScanState, verify_finalised
from slamfront.message_types import decode_json
from slamfront.text import shorten

if TYPE_CHECKING:
    from slamfront.message_types import MessageTypes

# A damaged summary section fails in many layers (record parsing, struct, CRC checks);
# every one of them means "scan the data section instead".
_READ_ERRORS = (Exception,)


@dataclass
class TopicSummary:
    """One topic of a log."""

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass
class LogSummary:
    """What a log holds. ``complete`` is False for a truncated file; ``problem`` says why."""

    path: str
    size_bytes: int
    topics: list[TopicSummary]
    complete: bool
    problem: str | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: list[str] = field(default_factory=list)
    salvaged_messages: int = 0
    """Messages read from the start of a chunk the file ends inside."""

    @property
    def n_messages(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def start_ns(self) -> int | None:
        firsts = [t.first_ns for t in self.topics if t.first_ns is not None]
        return min(firsts) if firsts else None

    @property
    def end_ns(self) -> int | None:
        lasts = [t.last_ns for t in self.topics if t.last_ns is not None]
        return max(lasts) if lasts else None

    def topic(self, name: str) -> TopicSummary:
        for topic in self.topics:
            if topic.topic == name:
                return topic
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data.update(n_messages=self.n_messages, start_ns=self.start_ns, end_ns=self.end_ns)
        span = None if self.start_ns is None else (self.end_ns - self.start_ns) / 1e9
        data["duration_s"] = span
        return data


@dataclass(frozen=True)
class LoggedMessage:
    """One message as stored, decodable on demand."""

    topic: str
    schema_name: str
    message_encoding: str
    log_time_ns: int
    sequence: int
    data: bytes
    schema_data: bytes = b""
    schema_encoding: str = ""
    publish_time_ns: int = 0
    types: MessageTypes | None = field(default=None, compare=False, repr=False)
    """The message types that decode JSON messages (None: slamfront's and the installed
    plugins', :mod:`slamfront.message_types`)."""

    @cached_property
    def decoded(self) -> Any:
        """A slamfront :class:`~slamfront.messages.Message` (or a dict when no installed
        package declares its type), or a protobuf object for Foxglove messages.

        :raises LogError: the bytes do not decode (a damaged or crafted message), naming
            the topic and the log time.
        """
        try:
            return self._decode()
        except LogError:
            raise
        except (
            ValueError, TypeError, KeyError, IndexError, AttributeError, RecursionError, DecodeError, McapError
        ) as exc:  # McapError: a protobuf schema that does not describe its type (a crafted channel)
            raise LogError(
                f"{self.topic} message at {self.log_time_ns} ns does not decode as {self.schema_name or 'its schema'}: "
                f"{type(exc).__name__}: {shorten(str(exc), 160)}"
            ) from None

    def _decode(self) -> Any:
        if self.message_encoding == "json":
            return decode_json(self.schema_name, self.data, self.types)
        if self.message_encoding == "protobuf":
            schema = Schema(id=0, name=self.schema_name, encoding="protobuf", data=self.schema_data)
            decoder = ProtobufDecoderFactory().decoder_for("protobuf", schema)
            if decoder is None:
                raise LogError(f"cannot decode protobuf schema {self.schema_name}")
            return decoder(self.data)
        raise LogError(f"unsupported message encoding {self.message_encoding!r} on {self.topic}")


def _open(path: Path) -> Any:
    """``path`` opened for reading; anything but a regular file (a FIFO, a device, a
    folder) is refused at once, never read from (a FIFO would block until written to)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise LogError(f"{path}: no such log file") from None
    except OSError as exc:
        raise LogError(f"{path}: cannot read log: {exc.strerror or exc}") from exc
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "not a regular file"
        raise LogError(f"{path}: is {kind}; a log is read only from a regular file")
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def writer_library(path: Path | str) -> str:
    """The ``library`` field of the log's MCAP header (who wrote it; ``""`` when unreadable).

    slamfront's writers start with ``slamfront`` and number each channel's messages 0, 1, 2, ...
    """
    with _open(Path(path)) as stream:
        head = stream.read(len(MAGIC) + 9)
        if head[: len(MAGIC)] != MAGIC or len(head) < len(MAGIC) + 9:
            return ""
        opcode, length = struct.unpack_from("<BQ", head, len(MAGIC))
        if opcode != Opcode.HEADER or length > 1 << 16:
            return ""
        try:
            return Header.read(ReadDataStream(io.BytesIO(stream.read(length)))).library
        except (ValueError, UnicodeDecodeError, struct.error, EndOfFile):
            return ""


def check_magic(path: Path, stream: Any) -> None:
    head = stream.read(len(MAGIC))
    stream.seek(0)
    if head != MAGIC:
        if MAGIC.startswith(head):
            raise LogError(f"{path}: too short to be an MCAP log ({len(head)} bytes): nothing can be read from it")
        raise LogError(f"{path}: not an MCAP file (bad magic bytes)")


def _ends_with_magic(stream: Any) -> bool:
    stream.seek(0, 2)
    if stream.tell() < 2 * len(MAGIC):
        stream.seek(0)
        return False
    stream.seek(-len(MAGIC), 2)
    tail = stream.read(len(MAGIC))
    stream.seek(0)
    return tail == MAGIC


def log_file(path: Path | str) -> Path:
    """A log path as users give it: a run folder stands for the ``run.mcap`` inside it."""
    path = Path(path)
    return path / "run.mcap" if path.is_dir() else path


def summarize(path: Path | str) -> LogSummary:
    """Summarise a log; never raises on damage (see :attr:`LogSummary.complete`).

    The summary section is used only when the file's CRCs cover every byte and hold;
    otherwise every record is read (and every chunk's CRC checked) to find the damage.

    :raises LogError: the file is missing or not MCAP at all.
    """
    path = Path(path)
    with _open(path) as stream:
        check_magic(path, stream)
        size = path.stat().st_size
        if _ends_with_magic(stream):
            problems, covered = verify_finalised(stream, size)
            if covered and not problems:
                try:
                    reader = make_reader(stream)
                    summary = reader.get_summary()
                    if summary is not None and summary.statistics is not None:
                        return _from_summary(path, size, reader, summary)
                except _READ_ERRORS:
                    pass  # no usable summary section: fall back to a scan
        stream.seek(0)
        return _scan(path, size, stream)


def _from_summary(path: Path, size: int, reader: Any, summary: Any) -> LogSummary:
    topics = []
    counts = summary.statistics.channel_message_counts
    spans: dict[int, list[int]] = {}
    for index in summary.chunk_indexes:
        for channel_id in index.message_index_offsets:
            span = spans.setdefault(channel_id, [index.message_start_time, index.message_end_time])
            span[0] = min(span[0], index.message_start_time)
            span[1] = max(span[1], index.message_end_time)
    for channel_id, channel in sorted(summary.channels.items()):
        schema = summary.schemas.get(channel.schema_id)
        first, last = spans.get(channel_id, (None, None))
        topics.append(
            TopicSummary(
                topic=channel.topic,
                schema_name=schema.name if schema else "",
                schema_encoding=schema.encoding if schema else "",
                message_encoding=channel.message_encoding,
                count=counts.get(channel_id, 0),
                first_ns=first,
                last_ns=last,
            )
        )
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    attachments = [a.name for a in reader.iter_attachments()]
    return LogSummary(str(path), size, topics, complete=True, metadata=metadata, attachments=attachments)


def _scan(path: Path, size: int, stream: Any) -> LogSummary:
    schemas: dict[int, Schema] = {}
    topics: dict[int, TopicSummary] = {}
    metadata: dict[str, dict[str, str]] = {}
    attachments: list[str] = []
    scanner = RecordScanner(stream, size)
    for record in scanner.records():
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in topics:
            schema = schemas.get(record.schema_id)
            topics[record.id] = TopicSummary(
                record.topic,
                schema.name if schema else "",
                schema.encoding if schema else "",
                record.message_encoding,
            )
        elif isinstance(record, Message) and record.channel_id not in topics:
            scanner.state.orphan_messages += 1
        elif isinstance(record, Message):
            topic = topics[record.channel_id]
            topic.count += 1
            topic.first_ns = record.log_time if topic.first_ns is None else min(topic.first_ns, record.log_time)
            topic.last_ns = record.log_time if topic.last_ns is None else max(topic.last_ns, record.log_time)
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Attachment):
            attachments.append(record.name)
    state = scanner.state
    lasts = [t.last_ns for t in topics.values() if t.last_ns is not None]
    damaged = bool(state.problems or state.orphan_messages)
    problem = describe_damage(state, max(lasts) if lasts else None) if damaged or not state.complete else None
    return LogSummary(
        str(path), size, list(topics.values()), complete=state.complete and not damaged,
        problem=problem, metadata=metadata, attachments=attachments,
        salvaged_messages=state.salvaged_messages,
    )


def describe_damage(state: ScanState, last_ns: int | None = None) -> str:
    """What a scan could not read, in words."""
    lost = state.size - state.data_end
    text = "; ".join(state.problems) if state.problems else "no footer"
    if state.skipped_bytes:
        text += f"; {state.skipped_bytes} bytes inside the file could not be read"
    if lost > 0 and not state.data_ended:
        text += f"; {lost} of {state.size} bytes ({100 * lost / max(state.size, 1):.1f} %) could not be read"
        if last_ns is not None:
            text += f": what was logged after {last_ns / 1e9:.3f} s (log time) is lost"
    if state.salvaged_messages:
        text += f"; {state.salvaged_messages} messages recovered from the incomplete chunk"
    if state.orphan_messages:
        text += f"; {state.orphan_messages} messages dropped: their channel was defined in data that was lost"
    return text


def read_messages(
    path: Path | str, topics: Iterable[str] | None = None, strict: bool = True, types: MessageTypes | None = None
) -> Iterator[LoggedMessage]:
    """Messages in the order they were written (from the readable part of a damaged file).

    :param topics: only these topics (all when None).
    :param strict: raise :class:`LogError` after the last readable message of a damaged
        or unfinished file; when False, stop quietly there.
    :param types: what decodes JSON messages (default: the installed message types).
    """
    for message in read_messages_and_gaps(path, topics, strict, types):
        if message is not None:
            yield message


def read_messages_and_gaps(
    path: Path | str, topics: Iterable[str] | None = None, strict: bool = True, types: MessageTypes | None = None
) -> Iterator[LoggedMessage | None]:
    """:func:`read_messages`, with ``None`` where damage made the scan lose or step over
    part of the file: what was written around it may be incomplete."""
    path = Path(path)
    wanted = set(topics) if topics is not None else None
    with _open(path) as stream:
        check_magic(path, stream)
        scanner = RecordScanner(stream, path.stat().st_size)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        data_ended = False
        damage = 0
        for record in scanner.records():
            if len(scanner.state.problems) != damage:
                damage = len(scanner.state.problems)
                yield None
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    scanner.state.orphan_messages += 1
                    continue
                if wanted is not None and channel.topic not in wanted:
                    continue
                schema = schemas.get(channel.schema_id)
                yield LoggedMessage(
                    topic=channel.topic,
                    schema_name=schema.name if schema else "",
                    message_encoding=channel.message_encoding,
                    log_time_ns=record.log_time,
                    sequence=record.sequence,
                    data=bytes(record.data),
                    schema_data=bytes(schema.data) if schema else b"",
                    schema_encoding=schema.encoding if schema else "",
                    publish_time_ns=record.publish_time,
                    types=types,
                )
            elif isinstance(record, DataEnd):
                data_ended = True
                break
        state = scanner.state
        if len(state.problems) != damage:
            yield None
        if strict and (state.problems or not data_ended or state.orphan_messages):
            raise LogError(f"{path}: {describe_damage(state)}")


def read_attachment(path: Path | str, name: str) -> bytes:
    """The data of the attachment called ``name``.

    :raises LogError: when the log has no such attachment.
    """
    path = Path(path)
    with _open(path) as stream:
        check_magic(path, stream)
        scanner = RecordScanner(stream, path.stat().st_size)
        for record in scanner.records():
            if isinstance(record, Attachment) and record.name == name:
                return bytes(record.data)
        if scanner.state.problems:
            raise LogError(f"{path}: no attachment {name!r} in the readable part ({describe_damage(scanner.state)})")
    raise LogError(f"{path}: the log has no attachment {name!r}")


RECIPE_ATTACHMENT = "recipe.yaml"


def embedded_recipe_text(path: Path | str) -> str:
    """The recipe a log embeds (attachment ``recipe.yaml``), as text.

    :raises LogError: the log has no such attachment, or it is not UTF-8 text.
    """
    data = read_attachment(path, RECIPE_ATTACHMENT)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LogError(f"{path}: the {RECIPE_ATTACHMENT} attachment is not UTF-8 text (byte {exc.start})") from None
