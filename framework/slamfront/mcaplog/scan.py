"""Reading an MCAP file record by record, as far as it can be read.

A log cut short (power loss, a full disk, a killed machine) has no summary section and
ends inside some record. :class:`RecordScanner` reads every complete record in file
order, opens chunks (checking their CRC), and at the cut salvages the complete messages
at the start of the partial chunk: the chunk's compressed stream is decompressed as far
as it goes. A chunk that fails its CRC is skipped and reading goes on after it, since
its length field still says where the next record starts. Nothing here raises on
damage; what was lost is described in :attr:`RecordScanner.problems`.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import IO, Any

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc

# Records a reader of the data section needs; indexes and statistics are rebuilt by any writer.
_PARSERS: dict[int, Any] = {
    Opcode.HEADER: Header.read,
    Opcode.FOOTER: Footer.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.METADATA: Metadata.read,
    Opcode.DATA_END: DataEnd.read,
}
_KNOWN = {int(op) for op in Opcode}


@dataclass
class ScanState:
    """What a scan found out about the file besides its records."""

    size: int
    complete: bool = False
    """The footer was reached: the file was finalised."""
    data_ended: bool = False
    """The data section's end was reached: every message record was seen."""
    data_end: int = 8
    """Byte offset just after the last record read in full."""
    problems: list[str] = field(default_factory=list)
    """What could not be read and why, in file order."""
    salvaged_messages: int = 0
    """Messages recovered from the start of a chunk cut short."""


class RecordScanner:
    """Iterate the readable records of an MCAP stream (chunks opened, in file order).

    :param stream: a binary stream positioned at the start of the file.
    :param size: the file's length in bytes.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self._stream = stream
        self.state = ScanState(size=size)

    def records(self) -> Iterator[McapRecord]:
        """Header, schemas, channels, messages, metadata, attachments, data end, footer.

        When the summary section is intact, its schemas and channels come first: a
        damaged chunk then does not take the channels it introduced with it.
        """
        state = self.state
        yield from self._summary_channels()
        if self._stream.read(8) != MAGIC:
            state.problems.append("not an MCAP file (bad magic bytes)")
            return
        in_summary = False
        while True:
            offset = self._stream.tell()
            head = self._stream.read(_RECORD_HEAD.size)
            if len(head) == 0:
                state.problems.append(f"the file ends at byte {offset} without a footer: the run did not finalise it")
                return
            if len(head) < _RECORD_HEAD.size:
                state.problems.append(f"cut inside a record header at byte {offset}")
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            if opcode == 0 or (opcode not in _KNOWN and opcode < 0x80):
                state.problems.append(f"unreadable data from byte {offset} (record opcode {opcode:#x})")
                return
            available = state.size - offset - _RECORD_HEAD.size
            if length > available:
                content = self._stream.read(available)
                if opcode == Opcode.CHUNK:
                    yield from self._salvage(offset, content)
                state.problems.append(
                    f"cut inside a {_name(opcode)} record at byte {offset}: the last "
                    f"{state.size - offset} bytes of the file are an incomplete record"
                )
                return
            content = self._stream.read(length)
            state.data_end = offset + _RECORD_HEAD.size + length
            if opcode == Opcode.FOOTER:
                state.complete = True
                if self._stream.read(len(MAGIC)) != MAGIC:
                    state.problems.append("the file ends inside its closing magic bytes")
                yield Footer.read(_reader(content))
                return
            if in_summary:
                continue  # repeated schemas/channels and indexes: the data section has it all
            if opcode == Opcode.CHUNK:
                yield from self._chunk(offset, content)
            elif opcode == Opcode.MESSAGE:
                yield Message.read(_reader(content), length)
            elif opcode in _PARSERS:
                try:
                    record = _PARSERS[opcode](_reader(content))
                except Exception as exc:  # noqa: BLE001 (a damaged record of any kind)
                    state.problems.append(f"damaged {_name(opcode)} record at byte {offset} skipped ({exc})")
                    continue
                in_summary = state.data_ended = opcode == Opcode.DATA_END
                yield record

    def _summary_channels(self) -> Iterator[McapRecord]:
        try:
            self._stream.seek(-len(MAGIC), io.SEEK_END)
            if self._stream.read(len(MAGIC)) == MAGIC:
                self._stream.seek(0)
                summary = make_reader(self._stream).get_summary()
                if summary is not None:
                    yield from summary.schemas.values()
                    yield from summary.channels.values()
        except Exception:  # noqa: BLE001 (no usable summary: the data section has to do)
            pass
        self._stream.seek(0)

    def _chunk(self, offset: int, content: bytes) -> Iterator[McapRecord]:
        try:
            _start, _end, size, crc, compression, records = _chunk_fields(content)
            data = _decompress(compression, records, size)
        except Exception as exc:  # noqa: BLE001 (bad lengths, unknown compression, codec errors)
            self.state.problems.append(f"damaged chunk at byte {offset} skipped ({type(exc).__name__}: {exc})")
            return
        if crc and zlib.crc32(data) != crc:
            self.state.problems.append(f"chunk at byte {offset} failed its CRC check: skipped")
            return
        yield from _inner_records(data, lambda: None)

    def _salvage(self, offset: int, content: bytes) -> Iterator[McapRecord]:
        """The complete messages at the start of a chunk whose end is missing."""
        try:
            _start, _end, _size, _crc, compression, records = _chunk_fields(content, partial=True)
            data = _decompress_prefix(compression, records)
        except Exception:  # noqa: BLE001 (too little of the chunk to read anything)
            return

        def count() -> None:
            self.state.salvaged_messages += 1

        yield from _inner_records(data, count)


def _name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode {opcode:#x}"


def _reader(content: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(content))


def _chunk_fields(content: bytes, partial: bool = False) -> tuple[int, int, int, int, str, bytes]:
    start, end, size, crc = _CHUNK_HEAD.unpack_from(content, 0)
    pos = _CHUNK_HEAD.size
    (name_length,) = struct.unpack_from("<I", content, pos)
    compression = content[pos + 4 : pos + 4 + name_length].decode()
    pos += 4 + name_length
    (records_length,) = struct.unpack_from("<Q", content, pos)
    records = content[pos + 8 : pos + 8 + records_length]
    if not partial and len(records) != records_length:
        raise ValueError("records length does not match the chunk length")
    return start, end, size, crc, compression, records


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        return lz4.frame.decompress(data)
    if compression == "":
        return data
    raise ValueError(f"unknown chunk compression {compression!r}")


def _decompress_prefix(compression: str, data: bytes) -> bytes:
    """As much of a truncated compressed stream as decodes."""
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompressobj().decompress(data)
    if compression == "lz4":
        return lz4.frame.LZ4FrameDecompressor().decompress(data)
    return data


def _inner_records(data: bytes, on_message: Any) -> Iterator[McapRecord]:
    """Schemas, channels and messages of a chunk's records, up to the first incomplete one."""
    pos = 0
    while pos + _RECORD_HEAD.size <= len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        body = pos + _RECORD_HEAD.size
        if opcode == 0 or body + length > len(data):
            return
        content = data[body : body + length]
        pos = body + length
        try:
            if opcode == Opcode.MESSAGE:
                record: McapRecord = Message.read(_reader(content), length)
            elif opcode == Opcode.SCHEMA:
                record = Schema.read(_reader(content))
            elif opcode == Opcode.CHANNEL:
                record = Channel.read(_reader(content))
            else:
                continue
        except Exception:  # noqa: BLE001 (garbage where a record should be: stop here)
            return
        if isinstance(record, Message):
            on_message()
        yield record
