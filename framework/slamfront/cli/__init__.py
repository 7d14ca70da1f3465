"""The ``slamfront`` command: a thin shell over library calls.

Each sub-command is a module here with ``add_parser(subparsers)`` and ``run(args) ->
int``; :data:`COMMANDS` lists them in the order ``--help`` shows them. User errors
(:class:`~slamfront.errors.SlamfrontError`) become one line on stderr and exit code 2;
when they stop a run, the line also says where the log written so far is. A plugin's
exception keeps its traceback, followed by the same line (exit code 1).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import traceback
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
from slamfront.errors import SlamfrontError, run_failure_of
from slamfront.logcapture import TerminalHandler
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


class _Version(argparse.Action):
    """``--version``, looked up only when asked (reading the package metadata costs ~20 ms)."""

    def __call__(self, parser: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        parser.exit(message=f"slamfront {slamfront.__version__}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slamfront",
        description="Plugin-based visual SLAM front end: run and replay recipes, inspect, compare and recover logs, list plugins, evaluate.",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="show the version and exit")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, help="what to do")
    for command in COMMANDS:
        command.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    terminal = TerminalHandler()  # plugins' and slamfront's warnings, above the progress bar
    logging.getLogger().addHandler(terminal)
    try:  # parsing too: a Ctrl-C while the parser imports plugins is one line, not a traceback
        parser = build_parser()
        if "_ARGCOMPLETE" in os.environ:  # the shell asks for completions (see docs: shell completion)
            import argcomplete

            argcomplete.autocomplete(parser)
        args = parser.parse_args(argv)
        return int(args.handler(args) or 0)
    except SlamfrontError as exc:
        failure = run_failure_of(exc)
        where = f" (the log written so far: {failure.log})" if failure else ""
        # one line, whatever the message quotes from a file (escapes shown, length capped)
        print(f"slamfront: error: {shorten(str(exc), 2000)}{where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        failure = run_failure_of(exc)
        finalised = f"; the log written so far is finalised: {failure.log}" if failure else ""
        print(f"slamfront: interrupted ({str(exc) or 'SIGINT'}){finalised}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `slamfront plugins | head`
        return 0
    except Exception as exc:
        failure = run_failure_of(exc)
        if failure is None:
            raise  # a bug outside any run: Python's own traceback says it all
        traceback.print_exc()  # a plugin's (or slamfront's) bug: its author needs the traceback
        print(
            f"slamfront: error: the run failed {failure.where}: {type(exc).__name__}: {exc}; "
            f"the log written so far is finalised: {failure.log}",
            file=sys.stderr,
        )
        return 1
    finally:
        logging.getLogger().removeHandler(terminal)


if __name__ == "__main__":
    sys.exit(main())
