"""``slamfront inspect LOG [--json] [--recipe] [--validate]``"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.errors import LogError

if TYPE_CHECKING:
    from slamfront.mcaplog.reader import LogSummary


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "inspect", help="summarise an MCAP log", description="Topics, schemas, message counts and time span of a log."
    )
    parser.add_argument("log", type=Path, help="an .mcap file (or a run folder holding run.mcap)")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--recipe", action="store_true", help="print the recipe the log embeds (YAML) and nothing else")
    parser.add_argument(
        "--validate", action="store_true",
        help="also decode every message and check each topic's schema is a Foxglove or a registered slamfront one",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.mcaplog.reader import log_file, read_attachment, summarize
    from slamfront.mcaplog.validate import validate_log

    path = log_file(args.log)
    if args.recipe:
        print(read_attachment(path, "recipe.yaml").decode(), end="")
        return 0
    summary = summarize(path)
    if args.json:
        print(json.dumps(summary.to_dict(), indent=2))
    else:
        _print_summary(summary)
    if not summary.complete:
        # what could be read is shown above; the exit status says the file is damaged
        raise LogError(f"{path}: {summary.problem}")
    if args.validate:
        validation = validate_log(path)
        for problem in validation.problems:
            print(f"INVALID: {problem}")
        if not validation.valid:
            raise LogError(f"{path}: {len(validation.problems)} problem(s) found by --validate")
        print(f"valid: {validation.n_messages} messages on {validation.n_topics} topics decoded")
    return 0


def _print_summary(summary: LogSummary) -> None:
    print(f"{summary.path}: {summary.size_bytes / 1e6:.2f} MB, {summary.n_messages} messages")
    if summary.start_ns is not None:
        print(f"time span: {(summary.end_ns - summary.start_ns) / 1e9:.3f} s")
    if not summary.complete:
        print(f"INCOMPLETE: only what could be read is listed ({summary.problem})")
    width = max((len(t.topic) for t in summary.topics), default=5)
    for topic in summary.topics:
        print(f"  {topic.topic:<{width}}  {topic.count:>7}  {topic.schema_name} ({topic.message_encoding})")
    for name, values in summary.metadata.items():
        shown = ", ".join(f"{k}={v}" for k, v in values.items())
        print(f"metadata {name}: {shown[:200]}")
    if summary.attachments:
        print(f"attachments: {', '.join(summary.attachments)}")
