"""``slamfront diff LOG_A LOG_B [--ignore TOPIC]... [--strict] [--json]``"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from slamfront.errors import LogError
from slamfront.text import printable


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "diff",
        help="compare two logs message by message (exit 0 identical, 1 different)",
        description=(
            "Compare two logs topic by topic and report the first differing message of each topic "
            "(topic, index, field). Timings are left out by default: the /log topic and the wall-time, "
            "rate and memory keys of /metrics and of the stage statistics. Exit 0 when identical, 1 when not, "
            "2 when a log is damaged or unreadable."
        ),
    )
    parser.add_argument("log_a", type=Path, help="first .mcap log (or run folder)")
    parser.add_argument("log_b", type=Path, help="second .mcap log (or run folder)")
    parser.add_argument("--ignore", action="append", default=[], metavar="TOPIC",
                        help="also leave out topics matching this glob, e.g. '/camera/*' (repeatable)")
    parser.add_argument("--strict", action="store_true",
                        help="compare everything, timings and the /log topic included")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument(
        "-p", "--plugin-module", action="append", default=[], metavar="MODULE",
        help="also know the message types this plugin module declares, for their volatile fields (repeatable)",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.mcaplog.diff import diff_logs
    from slamfront.mcaplog.reader import log_file, summarize

    a, b = log_file(args.log_a), log_file(args.log_b)
    for path in (a, b):
        summary = summarize(path)
        if not summary.complete:  # comparing what is readable could call two different logs identical
            raise LogError(f"{path}: the log is damaged ({summary.problem}); `slamfront recover` it, then diff the copy")
    types = None  # the installed message types, gathered only if a log has a plugin's message
    if args.plugin_module:
        from slamfront.registry import PluginRegistry

        types = PluginRegistry(modules=args.plugin_module).message_types()
    result = diff_logs(a, b, ignore=args.ignore, strict=args.strict, types=types)
    if args.json:
        print(json.dumps({
            "identical": result.identical,
            "topics_compared": result.topics_compared,
            "messages_compared": result.messages_compared,
            "ignored": result.ignored,
            "differences": [asdict(d) for d in result.differences],
        }, indent=2))
    elif result.identical:
        ignored = f" (left out: {', '.join(result.ignored)} and timing keys)" if not args.strict else ""
        print(f"identical: {result.messages_compared} messages on {result.topics_compared} topics{ignored}")
    else:
        for difference in result.differences:
            print(printable(difference.describe(), keep_newlines=False))
        print(f"{len(result.differences)} of {result.topics_compared} topics differ (A = {a}, B = {b})")
    return 0 if result.identical else 1
