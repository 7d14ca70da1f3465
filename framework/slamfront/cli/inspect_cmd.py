"""``slamfront inspect LOG [--json]``"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from slamfront.errors import LogError
from slamfront.mcaplog.reader import LogSummary, summarize


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "inspect", help="summarise an MCAP log", description="Topics, schemas, message counts and time span of a log."
    )
    parser.add_argument("log", type=Path, help="an .mcap file (or a run folder holding run.mcap)")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    path = args.log / "run.mcap" if args.log.is_dir() else args.log
    summary = summarize(path)
    if args.json:
        print(json.dumps(summary.to_dict(), indent=2))
    else:
        _print_summary(summary)
    if not summary.complete:
        # what could be read is shown above; the exit status says the file is damaged
        raise LogError(f"{path}: {summary.problem}")
    return 0


def _print_summary(summary: LogSummary) -> None:
    print(f"{summary.path}: {summary.size_bytes / 1e6:.2f} MB, {summary.n_messages} messages")
    if summary.start_ns is not None:
        print(f"time span: {(summary.end_ns - summary.start_ns) / 1e9:.3f} s")
    if not summary.complete:
        print("INCOMPLETE: only the complete chunks are listed")
    width = max((len(t.topic) for t in summary.topics), default=5)
    for topic in summary.topics:
        print(f"  {topic.topic:<{width}}  {topic.count:>7}  {topic.schema_name} ({topic.message_encoding})")
    for name, values in summary.metadata.items():
        shown = ", ".join(f"{k}={v}" for k, v in values.items())
        print(f"metadata {name}: {shown[:200]}")
    if summary.attachments:
        print(f"attachments: {', '.join(summary.attachments)}")
