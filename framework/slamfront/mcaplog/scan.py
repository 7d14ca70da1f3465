"""Reading an MCAP file record by record, as far as it can be read, checking everything.

A log cut short (power loss, a full disk, a killed machine) has no summary section and
ends inside some record. :class:`RecordScanner` reads every complete record in file
order, opens chunks (checking their CRC), and at the cut salvages the complete messages
at the start of the partial chunk: the chunk's compressed stream is decompressed as far
as it goes.

Damage anywhere else is found and stepped over, never trusted:

- a chunk that fails its CRC is skipped; one whose length field disagrees with its
  content is read by its content's own lengths when they hold (the CRC decides);
- after unreadable bytes (a garbage opcode, a length running past the file or across
  a record the index knows) reading *resynchronises*: on the next record the summary's
  index locates when the file has an intact summary, else on the next byte position
  that holds a well-formed chunk or the data-end record;
- the data section's CRC (``DataEnd``), the summary's CRC (``Footer``) and each
  attachment's CRC are checked, and bytes after the closing magic are reported;
- a chunk is decompressed only up to the size it declares, and only when that size is
  within the ``chunk_bytes`` limit (:mod:`slamfront.limits`): a few kilobytes cannot
  claim gigabytes.

Nothing here raises on damage; what was lost is described in :attr:`ScanState.problems`.
"""

from __future__ import annotations

import bisect
import io
import struct
import zlib
from collections.abc import Callable, Iterator
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

from slamfront.limits import current_limits, over_limit

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc
_FOOTER = struct.Struct("<BQQQI")  # opcode, length (20), summary start, summary offset start, summary crc
_FOOTER_CRC_PREFIX = _FOOTER.size - 4  # the summary CRC covers the footer up to its own field
_DATA_END = struct.Struct("<BQI")  # opcode, length (4), data section crc
_COMPRESSIONS = ("", "zstd", "lz4")
_NAME_MAX = 16  # longest compression name a chunk header may carry
_SEARCH_SPAN = _RECORD_HEAD.size + _CHUNK_HEAD.size + 4 + _NAME_MAX + 8  # enough to judge a chunk header
_BLOCK = 1 << 20

# Records a reader of the data section needs; indexes and statistics are rebuilt by any writer.
_PARSERS: dict[int, Any] = {
    Opcode.HEADER: Header.read,
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
    """The data section's end was reached."""
    data_end: int = 8
    """Byte offset just after the last record read in full."""
    problems: list[str] = field(default_factory=list)
    """What could not be read and why, in file order."""
    salvaged_messages: int = 0
    """Messages recovered from the start of a chunk cut short."""
    skipped_bytes: int = 0
    """Bytes inside the file that were stepped over (damaged chunks, unreadable stretches)."""
    orphan_messages: int = 0
    """Messages a reader dropped because their channel's definition was lost (counted by the reader)."""


@dataclass(frozen=True)
class _Footer:
    offset: int
    summary_start: int
    summary_crc: int
    crc_prefix: bytes
    """The footer's bytes its summary CRC covers."""

    @property
    def data_end_offset(self) -> int:
        return (self.summary_start or self.offset) - _DATA_END.size


def _read_footer(stream: IO[bytes], size: int) -> _Footer | None:
    """The footer, when the file ends with a well-formed one and the closing magic."""
    offset = size - len(MAGIC) - _FOOTER.size
    if offset < len(MAGIC) + _DATA_END.size:
        return None
    stream.seek(offset)
    tail = stream.read(_FOOTER.size + len(MAGIC))
    stream.seek(0)
    if len(tail) != _FOOTER.size + len(MAGIC) or tail[_FOOTER.size :] != MAGIC:
        return None
    opcode, length, summary_start, _offsets, crc = _FOOTER.unpack_from(tail)
    if opcode != Opcode.FOOTER or length != _FOOTER.size - _RECORD_HEAD.size:
        return None
    if summary_start > offset or 0 < summary_start < len(MAGIC) + _DATA_END.size:
        return None
    return _Footer(offset, summary_start, crc, tail[:_FOOTER_CRC_PREFIX])


def _crc_of_range(stream: IO[bytes], start: int, end: int, suffix: bytes = b"") -> int:
    crc = 0
    stream.seek(start)
    remaining = end - start
    while remaining > 0:
        block = stream.read(min(remaining, _BLOCK))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        remaining -= len(block)
    stream.seek(0)
    return zlib.crc32(suffix, crc)


def _data_crc(stream: IO[bytes], footer: _Footer) -> int | None:
    """The data section CRC ``DataEnd`` records (0: not computed), None when there is no
    ``DataEnd`` where the footer says the data section ends."""
    stream.seek(footer.data_end_offset)
    record = stream.read(_DATA_END.size)
    stream.seek(0)
    if len(record) != _DATA_END.size:
        return None
    opcode, length, crc = _DATA_END.unpack(record)
    return crc if opcode == Opcode.DATA_END and length == 4 else None


def verify_finalised(stream: IO[bytes], size: int) -> tuple[list[str], bool]:
    """Check a finalised file's CRCs without opening a chunk: the summary section's (in
    the footer) and the data section's (in ``DataEnd``, when the writer computed it).

    :returns: (problems, whether every byte of the data section was covered by a CRC).
    """
    footer = _read_footer(stream, size)
    if footer is None:
        return ["the file does not end with a footer and the closing magic bytes"], False
    problems = []
    summary_end = footer.offset
    if footer.summary_crc and _crc_of_range(
        stream, footer.summary_start or summary_end, summary_end, footer.crc_prefix
    ) != footer.summary_crc:
        problems.append("the summary section fails its CRC check")
    data_crc = _data_crc(stream, footer)
    if data_crc is None:
        problems.append("no data-end record where the footer says the data section ends")
        return problems, False
    if data_crc and _crc_of_range(stream, 0, footer.data_end_offset) != data_crc:
        problems.append("the data section fails its CRC check")
    return problems, bool(data_crc)


@dataclass(frozen=True)
class _Index:
    """What an intact summary (its CRC checked) says about the data section."""

    records: list[McapRecord]
    """Its schemas and channels."""
    offsets: list[int]
    """Sorted start offsets of the chunks, metadata and attachments it indexes."""
    lengths: dict[int, int]
    """Content length (after opcode and length) of the record at each offset."""


def _summary_index(stream: IO[bytes], size: int) -> _Index | None:
    footer = _read_footer(stream, size)
    if footer is None or not footer.summary_start:
        return None
    if footer.summary_crc and _crc_of_range(
        stream, footer.summary_start, footer.offset, footer.crc_prefix
    ) != footer.summary_crc:
        return None  # a damaged summary would misplace messages: use none of it
    try:
        stream.seek(0)
        summary = make_reader(stream).get_summary()
    except Exception:  # noqa: BLE001 (any damage the CRC did not cover: no usable summary)
        return None
    finally:
        stream.seek(0)
    if summary is None:
        return None
    spans = [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]
    spans += [(a.offset, a.length) for a in summary.attachment_indexes]
    spans += [(m.offset, m.length) for m in summary.metadata_indexes]
    lengths = {
        offset: length - _RECORD_HEAD.size
        for offset, length in spans
        if len(MAGIC) <= offset and length >= _RECORD_HEAD.size and offset + length <= footer.data_end_offset
    }
    records: list[McapRecord] = [*summary.schemas.values(), *summary.channels.values()]
    return _Index(records, sorted(lengths), lengths)


class RecordScanner:
    """Iterate the readable records of an MCAP stream (chunks opened, in file order).

    :param stream: a binary stream positioned at the start of the file.
    :param size: the file's length in bytes.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self._stream = stream
        self.state = ScanState(size=size)
        self._index: _Index | None = None
        self._crc = 0
        self._crc_valid = True

    # -- the main loop -------------------------------------------------------------------

    def records(self) -> Iterator[McapRecord]:
        """Header, schemas, channels, messages, metadata, attachments, data end, footer.

        When the summary section is intact, its schemas and channels come first: a
        damaged chunk then does not take the channels it introduced with it.
        """
        state = self.state
        self._index = _summary_index(self._stream, state.size)
        if self._index is not None:
            yield from self._index.records
        self._stream.seek(0)
        if self._stream.read(len(MAGIC)) != MAGIC:
            state.problems.append("not an MCAP file (bad magic bytes)")
            return
        self._crc = zlib.crc32(MAGIC)
        offset = len(MAGIC)
        summary_crc: int | None = None  # running CRC of the summary section, once it starts
        summary_start = 0
        while True:
            self._stream.seek(offset)
            head = self._stream.read(_RECORD_HEAD.size)
            if len(head) == 0:
                state.problems.append(f"the file ends at byte {offset} without a footer: the run did not finalise it")
                return
            if len(head) < _RECORD_HEAD.size:
                state.problems.append(f"cut inside a record header at byte {offset}")
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            available = state.size - offset - _RECORD_HEAD.size
            if opcode == Opcode.CHUNK and not state.data_ended:
                next_offset = yield from self._chunk_at(offset, length, available)
                if next_offset is None:
                    return
                offset = next_offset
                continue
            if state.data_ended and (opcode == 0 or length > available):
                state.problems.append(f"the summary section is unreadable from byte {offset}")
                return
            known = self._index.lengths.get(offset) if self._index is not None else None
            bad_opcode = opcode not in _KNOWN  # slamfront writes no private records: garbage
            end = offset + _RECORD_HEAD.size + length
            if bad_opcode or length > available or (known is not None and known != length) or (
                not state.data_ended and (self._crosses_index(offset, end) or self._false_footer(opcode, offset, end))
            ):
                what = f"record opcode {opcode:#x}" if bad_opcode else f"a {_name(opcode)} record of {length} bytes"
                resumed = self._resync(offset, f"unreadable data at byte {offset} ({what})")
                if resumed is None:
                    return
                offset = resumed
                continue
            content = self._stream.read(length)
            state.data_end = end
            if opcode == Opcode.FOOTER:
                yield from self._footer(offset, head + content, summary_crc, summary_start)
                return
            if state.data_ended:
                summary_crc = zlib.crc32(head + content, summary_crc or 0)
            elif opcode == Opcode.DATA_END:
                self._data_end(content)
                state.data_ended = True
                summary_crc, summary_start = 0, end
                yield DataEnd.read(_reader(content))
            else:
                self._add_crc(head, content)
                record = self._parse(opcode, content, offset)
                if record is not None:
                    yield record
            offset = end

    def _false_footer(self, opcode: int, offset: int, end: int) -> bool:
        """A footer opcode in the data section that is not followed by the closing magic."""
        if opcode != Opcode.FOOTER or end + len(MAGIC) > self.state.size:
            return False
        self._stream.seek(end)
        following = self._stream.read(len(MAGIC))
        self._stream.seek(offset + _RECORD_HEAD.size)
        return following != MAGIC or end - offset != _FOOTER.size

    def _parse(self, opcode: int, content: bytes, offset: int) -> McapRecord | None:
        if opcode == Opcode.MESSAGE:
            try:
                return Message.read(_reader(content), len(content))
            except Exception as exc:  # noqa: BLE001 (a damaged record of any kind)
                self.state.problems.append(f"damaged message record at byte {offset} skipped ({exc})")
                return None
        if opcode not in _PARSERS:
            return None  # indexes, statistics, private records: not needed to read the data
        if opcode == Opcode.ATTACHMENT and len(content) >= 4:
            (crc,) = struct.unpack_from("<I", content, len(content) - 4)
            if crc and zlib.crc32(content[:-4]) != crc:
                self.state.problems.append(f"attachment at byte {offset} failed its CRC check: skipped")
                return None
        try:
            return _PARSERS[opcode](_reader(content))
        except Exception as exc:  # noqa: BLE001 (a damaged record of any kind)
            self.state.problems.append(f"damaged {_name(opcode)} record at byte {offset} skipped ({exc})")
            return None

    def _add_crc(self, *parts: bytes) -> None:
        for part in parts:
            self._crc = zlib.crc32(part, self._crc)

    def _data_end(self, content: bytes) -> None:
        (expected,) = struct.unpack_from("<I", content) if len(content) >= 4 else (0,)
        if expected and self._crc_valid and self._crc != expected and not self.state.problems:
            self.state.problems.append(
                "the data section fails its CRC check (a record outside the chunks is damaged)"
            )

    def _footer(self, offset: int, record: bytes, summary_crc: int | None, summary_start: int) -> Iterator[McapRecord]:
        state = self.state
        state.complete = True
        footer = Footer.read(_reader(record[_RECORD_HEAD.size :]))
        if summary_crc is None:
            state.problems.append(f"no data-end record before the footer at byte {offset}")
        elif footer.summary_start not in (0, summary_start):
            state.problems.append(
                f"the footer says the summary starts at byte {footer.summary_start}, it starts at byte {summary_start}"
            )
        elif footer.summary_crc and zlib.crc32(record[:_FOOTER_CRC_PREFIX], summary_crc) != footer.summary_crc:
            state.problems.append("the summary section fails its CRC check")
        end = offset + len(record)
        if self._stream.read(len(MAGIC)) != MAGIC:
            state.problems.append("the file ends inside its closing magic bytes")
        elif end + len(MAGIC) < state.size:
            extra = state.size - end - len(MAGIC)
            state.problems.append(f"{extra} bytes of unexpected data after the end of the log (byte {end + len(MAGIC)})")
        yield footer

    # -- chunks --------------------------------------------------------------------------

    def _chunk_at(self, offset: int, length: int, available: int) -> Iterator[McapRecord]:
        """Read the chunk record at ``offset``; returns where reading goes on (None: stop)."""
        state = self.state
        head = self._stream.read(min(available, _SEARCH_SPAN - _RECORD_HEAD.size))
        declared = _chunk_length(head)
        if declared is None:
            if length > available or len(head) < _CHUNK_HEAD.size + 4:
                return (yield from self._cut_chunk(offset, available))
            return self._resync(offset, f"damaged chunk header at byte {offset}")
        if length == declared and length <= available:
            content = (head + self._stream.read(max(0, length - len(head))))[:length]
            self._add_crc(_RECORD_HEAD.pack(Opcode.CHUNK, length), content)
            yield from self._chunk(offset, content)
            state.data_end = offset + _RECORD_HEAD.size + length
            return state.data_end
        if declared > available:
            if length > available:  # the file ends inside this chunk
                return (yield from self._cut_chunk(offset, available))
            return self._resync(offset, f"damaged chunk at byte {offset} (its content runs past the end of the file)")
        # the length field disagrees with the content's own lengths: trust those if the CRC does
        self._crc_valid = False
        problem = f"chunk at byte {offset} has a damaged length field ({length}; its content says {declared})"
        self._stream.seek(offset + _RECORD_HEAD.size)
        content = self._stream.read(declared)
        before = len(state.problems)
        records = list(self._chunk(offset, content))
        if len(state.problems) > before:
            return self._resync(offset, problem)
        state.problems.append(problem + "; its content passed its CRC check and was kept")
        yield from records
        state.data_end = offset + _RECORD_HEAD.size + declared
        return state.data_end

    def _cut_chunk(self, offset: int, available: int) -> Iterator[McapRecord]:
        self._stream.seek(offset + _RECORD_HEAD.size)
        content = self._stream.read(available)
        yield from self._salvage(content)
        self.state.problems.append(
            f"cut inside a chunk record at byte {offset}: the last {self.state.size - offset} bytes of the file "
            "are an incomplete record"
        )
        return None

    def _chunk(self, offset: int, content: bytes) -> Iterator[McapRecord]:
        try:
            _start, _end, size, crc, compression, records = _chunk_fields(content)
            problem = over_limit("chunk_bytes", size, "its declared uncompressed size")
            if problem:
                raise ValueError(problem)
            data = _decompress(compression, records, size)
        except Exception as exc:  # noqa: BLE001 (bad lengths, unknown compression, codec errors)
            self._lost(offset, len(content), f"damaged chunk at byte {offset} skipped ({type(exc).__name__}: {exc})")
            return
        if crc and zlib.crc32(data) != crc:
            self._lost(offset, len(content), f"chunk at byte {offset} failed its CRC check: skipped")
            return
        yield from _inner_records(data, lambda: None)

    def _salvage(self, content: bytes) -> Iterator[McapRecord]:
        """The complete messages at the start of a chunk whose end is missing."""
        try:
            _start, _end, _size, _crc, compression, records = _chunk_fields(content, partial=True)
            data = _decompress_prefix(compression, records, current_limits().chunk_bytes)
        except Exception:  # noqa: BLE001 (too little of the chunk to read anything)
            return

        def count() -> None:
            self.state.salvaged_messages += 1

        yield from _inner_records(data, count)

    def _lost(self, offset: int, length: int, problem: str) -> None:
        self.state.problems.append(problem)
        self.state.skipped_bytes += _RECORD_HEAD.size + length

    # -- resynchronising -----------------------------------------------------------------

    def _crosses_index(self, start: int, end: int) -> bool:
        """A record spanning [start, end) would swallow a record the index knows."""
        if self._index is None:
            return False
        position = bisect.bisect_right(self._index.offsets, start)
        return position < len(self._index.offsets) and self._index.offsets[position] < end

    def _resync(self, offset: int, problem: str) -> int | None:
        """Where reading goes on after damage at ``offset``: the next record the index
        knows, else the next well-formed chunk or data-end record; None when none follows."""
        self._crc_valid = False
        resumed = None
        if self._index is not None:
            position = bisect.bisect_right(self._index.offsets, offset)
            if position < len(self._index.offsets):
                resumed = self._index.offsets[position]
        if resumed is None:
            resumed = self._search(offset + 1)
        if resumed is None:
            lost = self.state.size - offset
            self.state.problems.append(f"{problem}: no readable record follows, the last {lost} bytes are lost")
            return None
        self.state.skipped_bytes += resumed - offset
        self.state.problems.append(f"{problem}: {resumed - offset} bytes skipped, reading goes on at byte {resumed}")
        return resumed

    def _search(self, start: int) -> int | None:
        """The first offset from ``start`` holding a well-formed chunk or data-end record."""
        size = self.state.size
        block_start = start
        while block_start < size:
            self._stream.seek(block_start)
            block = self._stream.read(_BLOCK + _SEARCH_SPAN)
            candidates = sorted(
                i for token in (bytes([Opcode.CHUNK]), bytes([Opcode.DATA_END])) for i in _find_all(block, token, _BLOCK)
            )
            for i in candidates:
                if self._plausible(block_start + i, block[i : i + _SEARCH_SPAN]):
                    return block_start + i
            block_start += _BLOCK
        return None

    def _plausible(self, offset: int, head: bytes) -> bool:
        """Whether ``head`` (the bytes at ``offset``) starts a well-formed chunk or data end."""
        if len(head) < _RECORD_HEAD.size:
            return False
        opcode, length = _RECORD_HEAD.unpack_from(head)
        if opcode == Opcode.DATA_END:
            return length == 4
        if length > self.state.size - offset - _RECORD_HEAD.size:
            return False
        return _chunk_length(head[_RECORD_HEAD.size :]) == length


def _find_all(block: bytes, token: bytes, limit: int) -> Iterator[int]:
    position = block.find(token)
    while 0 <= position < limit:
        yield position
        position = block.find(token, position + 1)


def _name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode {opcode:#x}"


def _reader(content: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(content))


def _chunk_length(head: bytes) -> int | None:
    """A chunk's content length according to its own fields (None when they are not a
    chunk header: too short, an unknown compression)."""
    pos = _CHUNK_HEAD.size
    if len(head) < pos + 4:
        return None
    (name_length,) = struct.unpack_from("<I", head, pos)
    if name_length > _NAME_MAX or len(head) < pos + 4 + name_length + 8:
        return None
    try:
        compression = head[pos + 4 : pos + 4 + name_length].decode()
    except UnicodeDecodeError:
        return None
    if compression not in _COMPRESSIONS:
        return None
    (records_length,) = struct.unpack_from("<Q", head, pos + 4 + name_length)
    return pos + 4 + name_length + 8 + records_length


def _chunk_fields(content: bytes, partial: bool = False) -> tuple[int, int, int, int, str, bytes]:
    start, end, size, crc = _CHUNK_HEAD.unpack_from(content, 0)
    pos = _CHUNK_HEAD.size
    (name_length,) = struct.unpack_from("<I", content, pos)
    compression = content[pos + 4 : pos + 4 + name_length].decode()
    pos += 4 + name_length
    (records_length,) = struct.unpack_from("<Q", content, pos)
    records = content[pos + 8 : pos + 8 + records_length]
    if not partial and (len(records) != records_length or pos + 8 + records_length != len(content)):
        raise ValueError("records length does not match the chunk length")
    return start, end, size, crc, compression, records


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """Exactly ``size`` bytes from ``data``, never more (whatever the stream itself claims)."""
    if compression == "zstd":
        out = _read_bounded(zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True).read, size + 1)
    elif compression == "lz4":
        out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    elif compression == "":
        out = data
    else:
        raise ValueError(f"unknown chunk compression {compression!r}")
    if len(out) != size:
        got = f"more than {size}" if len(out) > size else str(len(out))
        raise ValueError(f"decompresses to {got} bytes, not the {size} declared")
    return out


def _read_bounded(read: Callable[[int], bytes], limit: int) -> bytes:
    parts, total = [], 0
    while total < limit:
        part = read(limit - total)
        if not part:
            break
        parts.append(part)
        total += len(part)
    return b"".join(parts)


def _decompress_prefix(compression: str, data: bytes, limit: int) -> bytes:
    """As much of a truncated compressed stream as decodes, at most ``limit`` bytes."""
    if compression == "zstd":
        reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
        parts, total = [], 0
        try:
            while total < limit:
                part = reader.read(min(_BLOCK, limit - total))
                if not part:
                    break
                parts.append(part)
                total += len(part)
        except zstandard.ZstdError:
            pass  # the cut: keep what decoded before it
        return b"".join(parts)
    if compression == "lz4":
        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=limit)
    return data[:limit]


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
