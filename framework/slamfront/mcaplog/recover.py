"""Rewriting a damaged or unfinished log into a valid one: ``slamfront recover LOG -o FIXED``.

Every message that can be read is kept (:mod:`slamfront.mcaplog.scan` also reads the
complete messages at the start of a chunk the file ends inside), with its bytes, times
and channel, and so are the metadata and attachments. The new file is a finalised MCAP
with a summary; a ``recovery`` metadata record and a last ``/log`` line say what was
lost, since the run's own last line is gone with the end of the file.

A record read twice (a duplicated chunk or message of a slamfront log, whose messages
are numbered per channel) is kept once. Signs that the file was changed after it was
written (messages duplicated, reordered or missing; a channel slamfront would not
write) are said too: the copy numbers its messages afresh, so it would no longer show them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Attachment, Channel, Message, Metadata, Schema

from slamfront.errors import LogError, SlamfrontError
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.reader import LoggedMessage, TopicSummary, check_magic, describe_damage
from slamfront.mcaplog.scan import RecordScanner
from slamfront.mcaplog.topics import LOG_TOPIC
from slamfront.mcaplog.validate import OrderCheck, channel_problem, numbered_log
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.outputs import make_folder, refuse_overwrite


@dataclass
class Recovery:
    """What :func:`recover_log` kept and what the source had lost."""

    source: Path
    target: Path
    messages: int
    topics: int
    metadata: int
    attachments: int
    was_complete: bool
    salvaged_messages: int
    problem: str | None
    changes: list[str] = field(default_factory=list)
    """What shows the source was changed after it was written, although its records read
    (duplicated, reordered or dropped messages; unreadable encodings): the copy keeps
    the messages as they are, renumbered, so these are said here and in its last ``/log`` line."""


def recover_log(source: Path, target: Path, compression: str = "zstd", chunk_size: int = 1 << 20) -> Recovery:
    """Copy everything readable from ``source`` into a new, finalised log at ``target``.

    The new log is written beside ``target`` and renamed onto it at the end, so a
    recovery that fails leaves no half file, and ``target`` is replaced only by a whole one.

    :raises LogError: ``source`` is missing or not an MCAP file, or ``target`` is
        ``source`` (compared as files on disk: hard links and bind mounts included).
    """
    source, target = Path(source), Path(target)
    if not source.is_file():
        what = "no such log file" if not source.exists() else "is not a regular file; a log is read only from a regular file"
        raise LogError(f"{source}: {what}")
    try:
        refuse_overwrite(target, [source], "recover writes a new file; choose another -o path than the damaged log")
    except SlamfrontError as exc:
        raise LogError(str(exc)) from None
    make_folder(target.parent, "folder of the recovered log")
    partial = target.with_name(f".{target.name}.partial-{os.getpid()}")
    try:
        recovery = _copy_readable(source, partial, target, compression, chunk_size)
        os.replace(partial, target)
    except OSError as exc:
        raise LogError(f"{target}: cannot write the recovered log: {exc.strerror or exc}") from None
    finally:
        partial.unlink(missing_ok=True)
    return recovery


def _copy_readable(source: Path, partial: Path, target: Path, compression: str, chunk_size: int) -> Recovery:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts = {"messages": 0, "metadata": 0, "attachments": 0}
    topics: set[str] = set()
    last_time = 0
    numbered = numbered_log(source)
    order, changes = OrderCheck(numbered), []
    seen: dict[tuple[str, int], tuple[int, int]] = {}  # a numbered log's messages, to keep a duplicated one once
    with open(source, "rb") as stream:
        check_magic(source, stream)
        scanner = RecordScanner(stream, source.stat().st_size)
        with RunLogWriter(partial, compression, chunk_size, library="slamfront recover") as log:
            for record in scanner.records():
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id not in channels:
                    scanner.state.orphan_messages += 1
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    schema = schemas.get(channel.schema_id)
                    data = bytes(record.data)
                    change = order.problem(LoggedMessage(
                        channel.topic, schema.name if schema else "", channel.message_encoding, record.log_time,
                        record.sequence, data,
                    ))
                    if change:
                        changes.append(change)
                    key, fingerprint = (channel.topic, record.sequence), (record.log_time, hash(data))
                    if numbered and seen.get(key) == fingerprint:
                        continue  # the same record read twice (a duplicated record): kept once
                    seen[key] = fingerprint
                    log.write_raw(
                        channel.topic,
                        schema.name if schema else "",
                        schema.encoding if schema else "",
                        bytes(schema.data) if schema else b"",
                        channel.message_encoding,
                        data,
                        record.log_time,
                        record.publish_time,
                    )
                    topics.add(channel.topic)
                    counts["messages"] += 1
                    last_time = max(last_time, record.log_time)
                elif isinstance(record, Metadata):
                    log.add_metadata(record.name, dict(record.metadata))
                    counts["metadata"] += 1
                elif isinstance(record, Attachment):
                    log.add_attachment(
                        record.name, record.media_type, bytes(record.data), record.log_time, record.create_time
                    )
                    counts["attachments"] += 1
            state = scanner.state
            damaged = not state.complete or state.problems or state.orphan_messages
            if damaged:  # records lost to damage leave gaps in the numbering: the damage says it
                changes = [c for c in changes if " missing" not in c]
            for channel in channels.values():
                schema = schemas.get(channel.schema_id)
                problem = channel_problem(TopicSummary(
                    channel.topic, schema.name if schema else "", schema.encoding if schema else "",
                    channel.message_encoding,
                ))
                if problem and problem not in changes:
                    changes.append(problem)
            complete = not damaged and not changes
            problem = describe_damage(state, last_time or None) if damaged else None
            if not complete:
                ended = "" if state.data_ended else "; how the run ended was not recorded"
                lost = f"lost: {problem}{ended}" if problem else "nothing lost"
                changed = f"; changed after it was written: {changes[0]} ({len(changes)} such)" if changes else ""
                text = (
                    f"log recovered by slamfront recover from {source.name}: {counts['messages']} messages kept; "
                    f"{lost}{changed}"
                )
                log.add_metadata(
                    "recovery",
                    {"source": str(source), "problem": problem or "", "messages_kept": counts["messages"],
                     "salvaged_messages": state.salvaged_messages, "changes": str(len(changes))},
                )
                log.write_foxglove(LOG_TOPIC, foxglove.log_line(text, last_time, "warning"), last_time)
    return Recovery(
        source=source, target=target, messages=counts["messages"], topics=len(topics), metadata=counts["metadata"],
        attachments=counts["attachments"], was_complete=complete, salvaged_messages=state.salvaged_messages,
        problem=problem, changes=changes,
    )
