"""Writing a run's MCAP log.

Two encodings share one file: Foxglove's protobuf schemas for things Foxglove draws
(images, poses, transforms, clouds, markers, log lines) and slamfront's JSON messages
(:mod:`slamfront.messages`) for stage outputs. The writer is finalised on close, also
when the run ends with an exception, so the file always has its summary and footer.

Messages reach the MCAP writer on a second thread, in batches, in the order they were
written (:class:`_Background`): building chunks, compressing them, their CRCs, the file's
hash and the writes run beside the stages (zstd, zlib, hashlib and file writes release
Python's lock), so a run whose log is large pays for it on the other core. Everything else
(channels, metadata, attachments, syncs, closing) waits for the batches before it, so the
file is the same bytes as written in one thread; a write that fails there fails the next
call here, and closing writes every batch handed over.

Power loss is what finalising cannot help with: whatever the operating system has not
put on disk is gone. Every ``sync_seconds`` the writer closes the chunk being filled
and fsyncs the file, so a power cut loses at most that many seconds of the run (and
:mod:`slamfront.mcaplog.scan` still reads the start of a chunk cut in two).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import AbstractContextManager
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Protocol

from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from slamfront.errors import LogError, SlamfrontError
from slamfront.mcaplog.reader import LoggedMessage
from slamfront.messages import Message
from slamfront.outputs import open_output

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

PROFILE = ""  # no ROS profile: Foxglove reads protobuf and jsonschema channels directly

logger = logging.getLogger(__name__)

BATCH_BYTES = 1 << 18
"""Message bytes handed to the writing thread at a time: few hand-offs (each costs a few
microseconds of locking), small enough that the two threads overlap within a chunk."""

MAX_PENDING_BATCHES = 8
"""Batches that may wait for the writing thread before a new one waits for the oldest:
memory stays bounded (about 2 MiB) when the disk is slower than the run."""


class _Background:
    """One worker thread that runs jobs in the order they are submitted; a job's error is
    raised in the caller's thread by the next :meth:`submit` or :meth:`wait`, and every job
    after a failed one is skipped (nothing is written after a failed write)."""

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._pending: deque[Future[None]] = deque()
        self._failed = False

    def _run(self, job: Callable[[], None]) -> None:
        if self._failed:
            return
        try:
            job()
        except BaseException:
            self._failed = True
            raise

    def submit(self, job: Callable[[], None]) -> None:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="slamfront-log")
        self._pending.append(self._pool.submit(self._run, job))
        while self._pending and (self._pending[0].done() or len(self._pending) > MAX_PENDING_BATCHES):
            self._pending.popleft().result()  # raises the job's error here

    def wait(self) -> None:
        """Wait for every job submitted so far (raising the first error)."""
        while self._pending:
            self._pending.popleft().result()

    def shutdown(self) -> None:
        """Wait for the jobs, errors or not, and stop the thread."""
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


class LogSink(Protocol):
    """Something that sees every channel and message as the log gets them (``--live``).

    A sink only watches: it gets the bytes the log stores, after they are stored, and a
    sink that fails is dropped with a warning; the log and the run go on.
    """

    def channel(self, channel_id: int, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes,
                message_encoding: str) -> None:
        """A new channel (topic) of the log."""

    def message(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        """A message of a channel announced before."""


class _HashedStream:
    """The log file, with a running SHA-256 and count of the bytes handed to it (the MCAP
    writer only appends), so what an fsync put on disk can be vouched for without reading it back."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self.sha256 = hashlib.sha256()
        self.size = 0

    def write(self, data: bytes) -> int:
        written = self._stream.write(data)
        self.sha256.update(data)
        self.size += len(data)
        return written

    def tell(self) -> int:
        return self.size

    def flush(self) -> None:
        self._stream.flush()

    def fileno(self) -> int:
        return self._stream.fileno()

    def close(self) -> None:
        self._stream.close()


class RunLogWriter:
    """An open MCAP file that stage outputs and Foxglove messages are written to.

    :param path: the ``.mcap`` file to create (overwritten if it exists; never through a link).
    :param compression: ``zstd``, ``lz4`` or ``none`` (chunk compression).
    :param chunk_size: bytes per chunk (before compression).
    :param library: written into the MCAP header.
    :param sync_seconds: close the current chunk and fsync at most this often (None: only
        when a chunk is full and at the end).
    :param critical: a context manager factory wrapped around every change to the file,
        so a signal cannot cut a record in two (see :class:`slamfront.interrupts.Interrupts`).
    :param on_sync: called on creation, after each fsync and after closing with the size of
        the file, the SHA-256 of its bytes and whether the file is finished
        (:meth:`slamfront.outputs.RunFolder.log_synced`).
    """

    def __init__(
        self,
        path: Path,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        library: str = "slamfront",
        sync_seconds: float | None = None,
        critical: Callable[[], AbstractContextManager[None]] = contextlib.nullcontext,
        on_sync: Callable[[int, str, bool], None] | None = None,
    ) -> None:
        self.path = Path(path)
        self._critical = critical
        self._on_sync = on_sync
        self._channels: dict[str, tuple[int, str]] = {}
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._protobuf_schema_data: dict[str, bytes] = {}
        self._json_schema_data: dict[str, bytes] = {}
        self._sequence: dict[int, int] = {}
        self._sinks: list[LogSink] = []
        self._batch: list[tuple[int, int, int, bytes, int]] = []
        self._batch_bytes = 0
        self._closed = False
        self._failed = False
        self._sync_seconds = sync_seconds
        self._last_sync = time.monotonic()
        self.n_messages = 0
        self.n_syncs = 0
        # Created, vouched for (an empty prefix on this inode) and given its header in one
        # section a signal cannot cut: a signal that arrived meanwhile is raised as the
        # section ends, and the log, already started, is then finalised before it goes on
        # (a caller whose constructor raised has no writer to close).
        started = False
        try:
            with self._changing():  # a failed header write is said like any other failed write
                try:
                    self._stream = _HashedStream(open_output(self.path))
                except SlamfrontError as exc:
                    raise LogError(str(exc)) from None
                except OSError as exc:
                    raise LogError(f"{self.path}: cannot create log: {exc.strerror or exc}") from exc
                if on_sync is not None:
                    on_sync(0, self._stream.sha256.hexdigest(), False)
                # data CRCs: readers can check every byte of the data section without opening a chunk
                self._writer = Writer(
                    self._stream, chunk_size=chunk_size, compression=_COMPRESSION[compression], enable_data_crcs=True
                )
                self._writer.start(profile=PROFILE, library=library)
                self._background = _Background()
                started = True
        except BaseException:
            if started:
                self.close()
            elif hasattr(self, "_stream"):
                with contextlib.suppress(OSError):
                    self._stream.close()
            raise

    # -- channels ------------------------------------------------------------------------

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, data)
        if key not in self._schemas:
            self._drain()
            self._schemas[key] = self._writer.register_schema(name=name, encoding=encoding, data=data)
        return self._schemas[key]

    def _channel(self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes, encoding: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            channel_id, known_schema = known
            if known_schema != schema_name:
                raise LogError(f"{self.path}: topic {topic} carries {known_schema}, cannot write {schema_name} to it")
            return channel_id
        # schema id 0 is MCAP's "no schema" (only met when copying a foreign log)
        schema_id = self._schema(schema_name, schema_encoding, schema_data) if schema_name or schema_encoding else 0
        self._drain()
        channel_id = self._writer.register_channel(topic=topic, message_encoding=encoding, schema_id=schema_id)
        self._channels[topic] = (channel_id, schema_name)
        self._tell_sinks("channel", channel_id, topic, schema_name, schema_encoding, schema_data, encoding)
        return channel_id

    def add_sink(self, sink: LogSink) -> None:
        """Let ``sink`` see every channel and message written from now on (add it before the first write)."""
        self._sinks.append(sink)

    def _tell_sinks(self, what: str, *args: Any) -> None:
        for sink in list(self._sinks):
            try:
                getattr(sink, what)(*args)
            except Exception as exc:  # noqa: BLE001 (a watcher must never stop the run or the log)
                self._sinks.remove(sink)
                logger.warning("%s stopped (%s: %s); the log is still written", type(sink).__name__,
                               type(exc).__name__, exc)

    def _json_schema(self, cls: type[Message]) -> bytes:
        if cls.schema_name not in self._json_schema_data:
            self._json_schema_data[cls.schema_name] = json.dumps(cls.json_schema()).encode()
        return self._json_schema_data[cls.schema_name]

    def _protobuf_schema(self, message_type: type) -> tuple[str, bytes]:
        name = message_type.DESCRIPTOR.full_name  # type: ignore[attr-defined]
        if name not in self._protobuf_schema_data:
            self._protobuf_schema_data[name] = build_file_descriptor_set(message_type).SerializeToString()
        return name, self._protobuf_schema_data[name]

    # -- writing -------------------------------------------------------------------------

    def _add(
        self, channel_id: int, log_time_ns: int, data: bytes | Callable[[], bytes], publish_time_ns: int | None = None,
        size_hint: int = 0,
    ) -> None:
        """Queue one message; ``data`` may be a function that makes its bytes on the writing
        thread (:meth:`write_foxglove_later`), ``size_hint`` then standing for its length."""
        sequence = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = sequence + 1
        published = log_time_ns if publish_time_ns is None else publish_time_ns
        self._batch.append((channel_id, log_time_ns, published, data, sequence))
        self._batch_bytes += len(data) if isinstance(data, bytes) else size_hint
        self.n_messages += 1
        if self._sinks:
            self._tell_sinks("message", channel_id, log_time_ns, data)
        if self._batch_bytes >= BATCH_BYTES:
            self._hand_off()
        if self._sync_seconds is not None and time.monotonic() - self._last_sync >= self._sync_seconds:
            self._sync()

    def _hand_off(self) -> None:
        """Give the messages batched so far to the writing thread (in a change section: its
        earlier failures are raised here)."""
        if not self._batch:
            return
        batch, self._batch, self._batch_bytes = self._batch, [], 0
        add = self._writer.add_message

        def write_batch() -> None:
            for channel_id, log_time, publish_time, data, sequence in batch:
                if not isinstance(data, bytes):
                    data = data()
                add(channel_id=channel_id, log_time=log_time, publish_time=publish_time, data=data, sequence=sequence)

        self._background_call(self._background.submit, write_batch)

    def _drain(self) -> None:
        """Everything written so far is in the MCAP writer (before any other call to it)."""
        self._hand_off()
        self._background_call(self._background.wait)

    def _background_call(self, call: Callable[..., None], *args: Any) -> None:
        """``call``, which raises what failed on the writing thread: any failure there (a full
        disk, a message that could not be built) leaves the log as it is on disk, unfinalised,
        as the thread skips every batch after it."""
        try:
            call(*args)
        except BaseException:
            self._failed = True
            raise

    @property
    def failed(self) -> bool:
        """A write failed (a full disk, say): the file stays as it is on disk, unfinalised."""
        return self._failed

    def _check_open(self) -> None:
        if self._closed:
            raise LogError(f"{self.path}: the log is already closed")
        if self._failed:
            raise LogError(f"{self.path}: the log cannot be written any more (an earlier write failed)")

    @contextlib.contextmanager
    def _changing(self) -> Iterator[None]:
        """A change to the file: not cut in two by a signal; a failed write (a full disk,
        a file-size limit) is the user's problem to fix, said in one line."""
        with self._critical():
            try:
                yield
            except OSError as exc:
                self._failed = True
                raise LogError(
                    f"{self.path}: cannot write the log: {exc.strerror or exc} (what reached the disk can be read "
                    "with `slamfront recover`)"
                ) from None

    def write(self, topic: str, message: Message, log_time_ns: int) -> None:
        """Write a slamfront message (JSON) on ``topic``."""
        self._check_open()
        data = message.to_json()
        schema = self._json_schema(type(message))
        with self._changing():
            channel = self._channel(topic, message.schema_name, "jsonschema", schema, "json")
            self._add(channel, log_time_ns, data)

    def write_foxglove(self, topic: str, message: Any, log_time_ns: int) -> None:
        """Write a protobuf message (a Foxglove schema) on ``topic``."""
        self._check_open()
        name, schema = self._protobuf_schema(type(message))
        data = message.SerializeToString()
        with self._changing():
            channel = self._channel(topic, name, "protobuf", schema, "protobuf")
            self._add(channel, log_time_ns, data)

    def write_foxglove_later(
        self, topic: str, message_type: type, build: Callable[[], Any], log_time_ns: int, size_hint: int
    ) -> None:
        """:meth:`write_foxglove` of the ``message_type`` that ``build`` returns, built on the
        writing thread in its place in the log: an image's compression releases Python's lock,
        so it runs beside the stages instead of between them. ``build`` must read only what
        nothing changes afterwards (its own copy of an image); ``size_hint`` is about the
        message's length. A sink watching the log (``--live``) needs the bytes now: then it is
        built here. An error in ``build`` fails a later call, as a failed write does."""
        if self._sinks:
            self.write_foxglove(topic, build(), log_time_ns)
            return
        self._check_open()
        name, schema = self._protobuf_schema(message_type)
        with self._changing():
            channel = self._channel(topic, name, "protobuf", schema, "protobuf")
            self._add(channel, log_time_ns, lambda: build().SerializeToString(), size_hint=size_hint)

    def write_raw(
        self,
        topic: str,
        schema_name: str,
        schema_encoding: str,
        schema_data: bytes,
        message_encoding: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Copy a message read from another log unchanged (bytes, schema and times)."""
        self._check_open()
        with self._changing():
            channel = self._channel(topic, schema_name, schema_encoding, schema_data, message_encoding)
            self._add(channel, log_time_ns, data, publish_time_ns)

    def copy(self, message: LoggedMessage) -> None:
        """Copy a message read from another log (:func:`~slamfront.mcaplog.reader.read_messages`)."""
        self.write_raw(
            message.topic, message.schema_name, message.schema_encoding, message.schema_data,
            message.message_encoding, message.data, message.log_time_ns, message.publish_time_ns,
        )

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record (string key/values), e.g. the run's versions."""
        self._check_open()
        with self._changing():
            self._drain()
            self._writer.add_metadata(name, {k: str(v) for k, v in values.items()})

    def add_attachment(
        self, name: str, media_type: str, data: bytes, log_time_ns: int = 0, create_time_ns: int | None = None
    ) -> None:
        """A file stored inside the log, e.g. the resolved recipe.

        Times default to 0 so two runs of one recipe store identical records.
        """
        self._check_open()
        created = log_time_ns if create_time_ns is None else create_time_ns
        with self._changing():
            self._drain()
            self._writer.add_attachment(
                create_time=created, log_time=log_time_ns, name=name, media_type=media_type, data=data
            )

    # -- durability ----------------------------------------------------------------------

    def _sync(self) -> None:
        self._drain()
        self._writer.flush()  # closes the current chunk and hands it to the OS
        os.fsync(self._stream.fileno())
        self._last_sync = time.monotonic()
        self.n_syncs += 1
        if self._on_sync is not None:
            self._on_sync(self._stream.size, self._stream.sha256.hexdigest(), False)

    def sync(self) -> None:
        """Put everything written so far on disk now (closes the current chunk)."""
        self._check_open()
        with self._changing():
            self._sync()

    # -- lifetime ------------------------------------------------------------------------

    def close(self) -> None:
        """Write the summary and footer, fsync and close the file. Safe to call twice."""
        if self._closed:
            return
        if self._failed:  # finishing would only fail again; keep what is on disk as it is
            self._closed = True
            self._background.shutdown()
            with contextlib.suppress(OSError):
                self._stream.close()
            return
        with self._changing():
            self._closed = True  # in the section: a signal cannot leave the log marked closed but unfinished
            try:
                try:
                    self._drain()  # every batch handed over is written before the summary
                finally:
                    self._background.shutdown()
                self._writer.finish()
                self._stream.flush()
                os.fsync(self._stream.fileno())
            finally:
                self._stream.close()
            # inside the section: a signal that arrived while finishing must not skip the record
            if self._on_sync is not None:  # the whole file: its hash without reading it back
                self._on_sync(self._stream.size, self._stream.sha256.hexdigest(), True)

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
