"""The ``slamfront`` command: a thin shell over library calls.

Each sub-command is a module here with ``add_parser(subparsers)`` and ``run(args) ->
int``; :data:`COMMANDS` lists them in the order ``--help`` shows them. User errors
(:class:`~slamfront.errors.SlamfrontError`) become one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import slamfront
from slamfront.cli import (
    compare_cmd,
    datasets_cmd,
    diff_cmd,
    eval_cmd,
    inspect_cmd,
    optimize_cmd,
    outliers_cmd,
    plugins_cmd,
    recover_cmd,
    replay_cmd,
    retrieval_cmd,
    run_cmd,
    shipped_cmd,
    sweep_cmd,
)
from slamfront.errors import SlamfrontError
from slamfront.text import shorten

COMMANDS = (
    run_cmd,
    replay_cmd,
    sweep_cmd,
    compare_cmd,
    eval_cmd,
    retrieval_cmd,
    plugins_cmd,
    inspect_cmd,
    diff_cmd,
    recover_cmd,
    shipped_cmd,
    datasets_cmd,
    optimize_cmd,
    outliers_cmd,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slamfront",
        description="Plugin-based visual SLAM front end: run and replay recipes, inspect, compare and recover logs, list plugins, evaluate.",
    )
    parser.add_argument("--version", action="version", version=f"slamfront {slamfront.__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        return int(args.handler(args) or 0)
    except SlamfrontError as exc:
        # one line, whatever the message quotes from a file (escapes shown, length capped)
        print(f"slamfront: error: {shorten(str(exc), 2000)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        log = getattr(exc, "log_path", None)
        finalised = f"; the log written so far is finalised: {log}" if log else ""
        print(f"slamfront: interrupted ({str(exc) or 'SIGINT'}){finalised}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `slamfront plugins | head`
        return 0


if __name__ == "__main__":
    sys.exit(main())
