"""Mutation fuzz of a real log through `inspect --validate`, `replay` and `recover`.

A short run of a shipped recipe writes the log (twice: zstd chunks as shipped, and
uncompressed chunks so that mutations reach the records inside them). Each case draws
one seeded mutation of one of three families and runs the three commands on the result
in this process (under an address-space limit):

- **damage** (what a disk, a copy or a tool does; the CRCs are left as they were): byte
  flips, truncation, zeroed runs, appended bytes, a top-level record's length field
  changed, a top-level record dropped or duplicated.
- **crafted** (a well-formed MCAP file, every CRC, index and summary right, each message
  keeping its sequence number as a tool moving records would): a message dropped (not the
  last of its channel), duplicated, or swapped with the next one of its channel; every
  ``/frames`` message written 2-3 times; two ``/frames`` messages swapped; a channel
  declared in another message encoding (``cbor``, ``msgpack``, ``ros1msg``, none, or
  json/protobuf swapped); a JSON channel declared with another slamfront schema.
- **inner** (uncompressed chunks, CRCs recomputed after the change): bytes flipped, or an
  inner record's length field changed, inside a chunk's records. Only robustness is
  judged here: such a file can be a well-formed log that says something else.

What is counted, per command:

- **traceback**: any exit that is not 0 or 2, a Python traceback, a hang (over
  ``--timeout`` s), or an exit 2 whose error is not one line (``slamfront: note:`` and
  ``warning:`` lines may come before it).
- **success on damage**: the mutation changed what a reader decodes, and yet
  ``inspect --validate`` or ``replay`` (without ``--salvage``) exits 0, or ``recover``
  exits 0 saying "complete and undamaged" or without a ``lost:``/``changed:`` line (or,
  for damage, keeps a message the original did not have). "What a reader decodes" is
  judged by the ``mcap`` library's own stream reader with CRC checks, independent of
  slamfront's scanner: the header, every schema, channel and message (topic, encodings,
  schema, times, sequence number, bytes), metadata and attachment of the data section.
  Counted for the damage and crafted families; for inner mutations exit 0 on a changed
  file is listed for information only.

Goal: 0 tracebacks and 0 successes on damage. Results: benchmarks/results/log_fuzz.md.

Run: nice .venv/bin/python benchmarks/bench_log_fuzz.py [--cases 500] [--seed 0]
     [--recipe paired_demo] [--frames 40]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import os
import platform
import random
import resource
import struct
import sys
import tempfile
import time
import traceback
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))

from common import peak_rss_mb, publish, table  # noqa: E402

from tests import crafted_logs  # noqa: E402
from tests.test_hostile_inputs import _CaseTimeout, _time_limit, record_offsets  # noqa: E402

MAGIC = b"\x89MCAP0\r\n"
CHUNK, DATA_END = 0x06, 0x0F
ADDRESS_SPACE = 4 << 30
COMMANDS = ("inspect --validate", "replay", "recover")


# -- what a reader decodes, independently of slamfront ----------------------------------------


def decoded_content(path: Path) -> tuple[Any, ...]:
    """The data section as the ``mcap`` library's stream reader (CRCs checked) reads it."""
    from mcap.records import Attachment, Channel, DataEnd, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    items: list[Any] = []
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, validate_crcs=True, record_size_limit=1 << 28).records:
                if isinstance(record, Header):
                    items.append(("header", record.profile, record.library))
                elif isinstance(record, Schema):
                    schemas[record.id] = (record.name, record.encoding, bytes(record.data))
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, record.message_encoding, record.schema_id)
                elif isinstance(record, Message):
                    topic, encoding, schema_id = channels[record.channel_id]
                    items.append(("message", topic, encoding, schemas.get(schema_id), record.log_time,
                                  record.publish_time, record.sequence, bytes(record.data)))
                elif isinstance(record, Metadata):
                    items.append(("metadata", record.name, sorted(record.metadata.items())))
                elif isinstance(record, Attachment):
                    items.append(("attachment", record.name, record.media_type, bytes(record.data)))
                elif isinstance(record, DataEnd):
                    break
            else:
                items.append(("no data end",))
    except Exception as exc:  # noqa: BLE001 - any failure to read is a difference
        items.append(("unreadable", type(exc).__name__))
    return tuple(items)


def messages_of(content: tuple[Any, ...]) -> collections.Counter[Any]:
    return collections.Counter((item[1], item[4], item[7]) for item in content if item[0] == "message")


# -- mutations --------------------------------------------------------------------------------


def damage(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """One accident, the CRCs left as they were."""
    records = record_offsets(data)
    kind = rng.choice(("flip", "truncate", "zero", "append", "length", "record_drop", "record_dup"))
    mutated = bytearray(data)
    if kind == "flip":
        for _ in range(rng.randint(1, 3)):
            mutated[rng.randrange(len(mutated))] ^= rng.randint(1, 255)
    elif kind == "truncate":
        mutated = mutated[: rng.randrange(len(mutated))]
    elif kind == "zero":
        start = rng.randrange(len(mutated))
        end = min(len(mutated), start + rng.randint(1, 512))
        mutated[start:end] = bytes(end - start)
    elif kind == "append":
        mutated += rng.randbytes(rng.randint(1, 4096)) if rng.random() < 0.5 else data[rng.randrange(len(data)):]
    elif kind == "length":
        offset, _, length = rng.choice(records)
        new = rng.choice((0, length + rng.randint(1, 64), max(0, length - rng.randint(1, 64)), rng.getrandbits(63),
                          length ^ (1 << rng.randrange(40))))
        struct.pack_into("<Q", mutated, offset + 1, new)
    else:
        offset, _, length = rng.choice(records[1:-1] or records)
        record = data[offset : offset + 9 + length]
        if kind == "record_drop":
            mutated = bytearray(data[:offset] + data[offset + 9 + length :])
        else:
            mutated = bytearray(data[: offset + 9 + length] + record + data[offset + 9 + length :])
    return kind, bytes(mutated)


def crafted(content: crafted_logs.LogContent, rng: random.Random, target: Path) -> str:
    """One well-formed change that breaks what slamfront's writer guarantees."""
    messages = list(content.messages)
    by_topic: dict[str, list[int]] = collections.defaultdict(list)
    for index, message in enumerate(messages):
        by_topic[message.topic].append(index)
    several = [topic for topic, where in by_topic.items() if len(where) >= 2]
    kind = rng.choice(("msg_drop", "msg_dup", "msg_swap", "frames_repeat", "frames_swap", "encoding", "schema_name"))
    change: Callable[[list[crafted_logs.Entry]], list[crafted_logs.Entry]]
    if kind == "msg_drop":
        topic = rng.choice(several)
        position = rng.choice(by_topic[topic][:-1])
        change = lambda m: m[:position] + m[position + 1 :]  # noqa: E731
    elif kind == "msg_dup":
        position = rng.randrange(len(messages))
        later = rng.randint(position + 1, len(messages))
        change = lambda m: m[:later] + [m[position]] + m[later:]  # noqa: E731
    elif kind == "msg_swap":
        topic = rng.choice(several)
        first = rng.randrange(len(by_topic[topic]) - 1)
        change = crafted_logs.swapped(topic, first, renumber=False)
    elif kind == "frames_repeat":
        change = crafted_logs.repeated("/frames", rng.choice((2, 3)))
    elif kind == "frames_swap":
        change = crafted_logs.swapped("/frames", rng.randrange(len(by_topic["/frames"]) - 1))
    elif kind == "encoding":
        topic = rng.choice(sorted(by_topic))
        old = messages[by_topic[topic][0]].encoding
        new = rng.choice(("cbor", "msgpack", "ros1msg", "", "protobuf" if old == "json" else "json"))
        change = crafted_logs.with_encoding(topic, new)
        kind = f"encoding {new or 'none'}"
    else:
        json_topics = sorted(t for t, where in by_topic.items() if messages[where[0]].encoding == "json")
        topic = rng.choice(json_topics)
        names = sorted({m.schema_name for m in messages if m.encoding == "json"} - {messages[by_topic[topic][0]].schema_name})
        name = rng.choice(names)
        change = lambda m: [replace(e, schema_name=name) if e.topic == topic else e for e in m]  # noqa: E731
    mutated = crafted_logs.LogContent(content.library, change(messages), content.metadata, content.attachments)
    crafted_logs.write_content(mutated, target)
    return kind


def inner(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """Bytes (or an inner record's length) changed inside an uncompressed chunk, its CRC
    and the data section's CRC recomputed."""
    mutated = bytearray(data)
    chunks = [(offset, length) for offset, opcode, length in record_offsets(data) if opcode == CHUNK]
    offset, _ = rng.choice(chunks)
    body = offset + 9
    crc_at = body + 24
    (name_length,) = struct.unpack_from("<I", data, crc_at + 4)
    records_at = crc_at + 8 + name_length + 8
    (records_length,) = struct.unpack_from("<Q", data, records_at - 8)
    kind = rng.choice(("inner_flip", "inner_length"))
    if kind == "inner_flip":
        for _ in range(rng.randint(1, 3)):
            mutated[records_at + rng.randrange(records_length)] ^= rng.randint(1, 255)
    else:
        inner_offsets, position = [], records_at
        while position + 9 <= records_at + records_length:
            inner_offsets.append(position)
            position += 9 + struct.unpack_from("<Q", data, position + 1)[0]
        where = rng.choice(inner_offsets)
        (length,) = struct.unpack_from("<Q", data, where + 1)
        new = rng.choice((0, length + rng.randint(1, 64), max(0, length - rng.randint(1, 64)), rng.getrandbits(63),
                          length ^ (1 << rng.randrange(40))))
        struct.pack_into("<Q", mutated, where + 1, new)
    struct.pack_into("<I", mutated, crc_at, zlib.crc32(mutated[records_at : records_at + records_length]))
    data_end = next(o for o, opcode, _ in record_offsets(data) if opcode == DATA_END)
    struct.pack_into("<I", mutated, data_end + 9, zlib.crc32(mutated[:data_end]))
    return kind, bytes(mutated)


# -- running the commands -----------------------------------------------------------------------


def call(argv: list[str], timeout: int) -> tuple[Any, str, str, float]:
    from slamfront.cli import main

    out, err = io.StringIO(), io.StringIO()
    started = time.perf_counter()
    try:
        with _time_limit(timeout), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code: Any = main(argv)
    except _CaseTimeout:
        code = "hang"
    except BaseException:  # noqa: BLE001 - a traceback is what the fuzz counts
        code = "traceback"
        err.write(traceback.format_exc())
    return code, out.getvalue(), err.getvalue(), time.perf_counter() - started


def judge(command: str, family: str, code: Any, out: str, err: str, changed: bool,
          invented: bool) -> tuple[bool, bool]:
    """(traceback, success on damage) for one command's outcome."""
    broken = code not in (0, 2) or "Traceback" in err or "Traceback" in out
    lines = err.splitlines()
    errors = [line for line in lines if line.startswith("slamfront: error: ")]
    others = [line for line in lines if not line.startswith(("slamfront: error: ", "slamfront: note: ", "slamfront: warning: "))]
    if code == 2 and (len(errors) != 1 or others):
        broken = True  # an error is one line (notes such as "held a previous run" may come before it)
    success = False
    if code == 0 and changed and family != "inner":
        if command in ("inspect --validate", "replay"):
            success = True
        else:
            honest = ("lost:" in out or "changed:" in out) and "complete and undamaged" not in out
            success = not honest or (family == "damage" and invented)
    return broken, success


def make_logs(recipe: str, frames: int, folder: Path) -> tuple[Path, Path]:
    from slamfront.cli import main

    logs = []
    for compression in ("zstd", "none"):
        out = folder / f"base_{compression}"
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(["run", recipe, "-o", str(out), "-q", "--max-frames", str(frames),
                         "--set", "log.chunk_size=16384", "--set", f"log.compression={compression}"])
        assert code == 0, f"the base run of {recipe} failed"
        logs.append(out / "run.mcap")
    return logs[0], logs[1]


def cpu_model() -> str:
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--recipe", default="paired_demo")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--timeout", type=int, default=120, help="seconds before a command counts as hung")
    parser.add_argument("--no-publish", action="store_true", help="print the table only")
    args = parser.parse_args()
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))
    os.environ.update({name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="slamfront-fuzz-") as scratch:
        folder = Path(scratch)
        zstd_log, plain_log = make_logs(args.recipe, args.frames, folder)
        bases = {"zstd": (zstd_log.read_bytes(), decoded_content(zstd_log)),
                 "none": (plain_log.read_bytes(), decoded_content(plain_log))}
        content = crafted_logs.read_content(zstd_log)
        rss_before = peak_rss_mb()
        counts: dict[tuple[str, str], collections.Counter[str]] = collections.defaultdict(collections.Counter)
        failures: list[str] = []
        seconds: collections.Counter[str] = collections.Counter()
        bar = tqdm(range(args.cases), desc="log fuzz", unit="case")
        for case in bar:
            rng = random.Random(args.seed * 1_000_003 + case)
            family = rng.choices(("damage", "crafted", "inner"), weights=(50, 35, 15))[0]
            path = folder / "mutated.mcap"
            base = "none" if family == "inner" else "zstd"
            if family == "damage":
                kind, data = damage(bases[base][0], rng)
                path.write_bytes(data)
            elif family == "crafted":
                kind = crafted(content, rng, path)
            else:
                kind, data = inner(bases[base][0], rng)
                path.write_bytes(data)
            mutated = decoded_content(path)
            changed = mutated != bases[base][1]
            row = counts[(family, kind)]
            row["cases"] += 1
            row["changed"] += changed
            for command in COMMANDS:
                argv = {"inspect --validate": ["inspect", str(path), "--validate"],
                        "replay": ["replay", str(path), "-o", str(folder / "replayed"), "-q"],
                        "recover": ["recover", str(path), "-o", str(folder / "fixed.mcap")]}[command]
                code, out, err, took = call(argv, args.timeout)
                seconds[command] += took
                invented = False
                if command == "recover" and code == 0 and family == "damage":
                    kept = messages_of(decoded_content(folder / "fixed.mcap"))
                    kept = collections.Counter({k: n for k, n in kept.items() if k[0] != "/log"})
                    invented = bool(kept - messages_of(bases[base][1]))
                broken, success = judge(command, family, code, out, err, changed, invented)
                row[f"{command}: exit {code if code in (0, 2) else 'other'}"] += 1
                row[f"{command}: traceback"] += broken
                row[f"{command}: success on damage"] += success
                if code == 0 and changed and family == "inner" and (
                        command != "recover" or "complete and undamaged" in out):
                    row[f"{command}: exit 0 on a changed well-formed file"] += 1
                if broken or success:
                    what = "traceback" if broken else "success on damage"
                    failures.append(f"case {case} ({family}/{kind}), {command}: {what}: {(err or out).strip()[-600:]}")
            total = collections.Counter()
            for values in counts.values():
                total.update(values)
            bar.set_postfix(tracebacks=sum(total[f"{c}: traceback"] for c in COMMANDS),
                            successes=sum(total[f"{c}: success on damage"] for c in COMMANDS), refresh=False)
        bar.close()
    elapsed = time.perf_counter() - started
    report(args, counts, failures, seconds, elapsed, rss_before)


def report(args: argparse.Namespace, counts: dict[tuple[str, str], collections.Counter[str]], failures: list[str],
           seconds: collections.Counter[str], elapsed: float, rss_before: float) -> None:
    rows, totals = [], collections.Counter()
    for (family, kind), row in sorted(counts.items()):
        totals.update(row)
        rows.append([family, kind, row["cases"], row["changed"],
                     *(f"{row[f'{c}: exit 0']}/{row[f'{c}: exit 2']}/{row[f'{c}: exit other']}" for c in COMMANDS),
                     sum(row[f"{c}: traceback"] for c in COMMANDS),
                     sum(row[f"{c}: success on damage"] for c in COMMANDS)])
    rows.append(["all", "", totals["cases"], totals["changed"],
                 *(f"{totals[f'{c}: exit 0']}/{totals[f'{c}: exit 2']}/{totals[f'{c}: exit other']}" for c in COMMANDS),
                 sum(totals[f"{c}: traceback"] for c in COMMANDS), sum(totals[f"{c}: success on damage"] for c in COMMANDS)])
    per_command = [[c, totals[f"{c}: traceback"], totals[f"{c}: success on damage"],
                    totals[f"{c}: exit 0 on a changed well-formed file"], f"{seconds[c] / max(1, totals['cases']):.3f}"]
                   for c in COMMANDS]
    command = (f"nice .venv/bin/python benchmarks/bench_log_fuzz.py --cases {args.cases} --seed {args.seed} "
               f"--recipe {args.recipe} --frames {args.frames}")
    body = "\n".join([
        f"Command: `{command}` ({elapsed / 60:.1f} min; a shared 2-core machine, run under `nice`).",
        f"Machine: {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}.",
        "",
        f"The log: `slamfront run {args.recipe} --max-frames {args.frames} --set log.chunk_size=16384` (zstd; and "
        "`--set log.compression=none` for the inner mutations). Each case is one seeded mutation, run through "
        "`inspect --validate`, `replay` and `recover` in one process (address space limited to "
        f"{ADDRESS_SPACE >> 30} GiB). The families and what counts as a traceback or a success on damage are "
        "defined in the script's docstring; in short, a success on damage is an exit 0 of `inspect --validate` or "
        "`replay` (or a `recover` that does not say what was lost or changed) on a file whose decoded content "
        "(as the `mcap` library's own CRC-checking reader reads the data section) differs from the original's.",
        "",
        "## Totals per command",
        "",
        table(["command", "tracebacks", "successes on damage",
               "inner: exit 0 (recover: 'undamaged') on a changed file, for information", "mean s per case"],
              per_command),
        "",
        f"Peak resident memory of the whole fuzz process: {peak_rss_mb():.0f} MB ({rss_before:.0f} MB after the "
        "two base runs, before the first case).",
        "",
        "## Per mutation",
        "",
        "Exit codes are `0/2/other` counts. *changed*: cases whose decoded content differs from the original's.",
        "",
        table(["family", "mutation", "cases", "changed", *(f"{c} 0/2/other" for c in COMMANDS), "tracebacks",
               "successes on damage"], rows),
        "",
        "## Failures",
        "",
        *(f"- {line}".replace("\n", " ") for line in failures[:30]),
        *(["- none"] if not failures else []),
    ])
    if args.no_publish:
        print(body)
    else:
        publish("log_fuzz", "Log mutation fuzz: inspect --validate, replay, recover", body)


if __name__ == "__main__":
    main()
