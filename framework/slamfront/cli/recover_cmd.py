"""``slamfront recover LOG -o FIXED``"""

from __future__ import annotations

import argparse
from pathlib import Path

from slamfront.text import shorten


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "recover",
        help="rewrite a truncated or unfinished log into a valid one",
        description=(
            "Copy every readable message, metadata record and attachment of LOG (a file cut short by a "
            "power loss, say) into a new, finalised MCAP file FIXED, and say what was lost."
        ),
    )
    parser.add_argument("log", type=Path, help="the damaged .mcap file")
    parser.add_argument("-o", "--out", type=Path, required=True, metavar="FIXED", help="the .mcap file to write")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.mcaplog.reader import log_file
    from slamfront.mcaplog.recover import recover_log

    recovery = recover_log(log_file(args.log), log_file(args.out))
    kept = (
        f"{recovery.messages} messages on {recovery.topics} topics, {recovery.metadata} metadata records, "
        f"{recovery.attachments} attachments"
    )
    if recovery.was_complete:
        print(f"{recovery.source} was complete and undamaged; copied {kept} to {recovery.target}")
    else:
        salvaged = f" ({recovery.salvaged_messages} from the incomplete last chunk)" if recovery.salvaged_messages else ""
        print(f"recovered {kept}{salvaged} into {recovery.target}")
        if recovery.problem:
            print(f"lost: {shorten(recovery.problem, 4000)}")
        if recovery.changes:
            print(f"changed: {len(recovery.changes)} sign(s) that {recovery.source} was changed after it was written, "
                  f"the first: {shorten(recovery.changes[0], 400)}")
    return 0
