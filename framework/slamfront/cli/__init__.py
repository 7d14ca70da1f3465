"""The ``slamfront`` command: a thin shell over library calls.

Each sub-command is a module here with ``add_parser(subparsers)`` and ``run(args) ->
int``; :data:`COMMANDS` lists them in the order ``--help`` shows them. User errors
(:class:`~slamfront.errors.SlamfrontError`) become one line on stderr and exit code 2;
when they stop a run, the line also says where the log written so far is. A plugin's
exception keeps its traceback, followed by the same line (exit code 1).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

import slamfront
from slamfront.errors import SlamfrontError, run_failure_of
from slamfront.text import shorten

COMMANDS = {
    "run": "run_cmd",
    "replay": "replay_cmd",
    "sweep": "sweep_cmd",
    "compare": "compare_cmd",
    "eval": "eval_cmd",
    "retrieval": "retrieval_cmd",
    "plugins": "plugins_cmd",
    "inspect": "inspect_cmd",
    "diff": "diff_cmd",
    "recover": "recover_cmd",
    "recipes": "shipped_cmd",
    "sweeps": "shipped_cmd",
    "layout": "shipped_cmd",
    "datasets": "datasets_cmd",
    "optimize": "optimize_cmd",
    "outliers": "outliers_cmd",
}
"""Each sub-command and the module of this package that defines it (in ``--help`` order).
Only the module of the command given is imported: ``slamfront recipes`` costs little
more than starting Python."""

QUIET_COMMANDS = frozenset({"recipes", "sweeps", "layout", "datasets"})
"""Listing commands that log nothing (they print): they skip the terminal log handler,
whose ``logging`` import is a tenth of what they cost."""


class _Version(argparse.Action):
    """``--version``, looked up only when asked (reading the package metadata costs ~20 ms)."""

    def __call__(self, parser: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        parser.exit(message=f"slamfront {slamfront.__version__}\n")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command line; with ``argv``, only the sub-command it names is built (when it names one)."""
    parser = argparse.ArgumentParser(
        prog="slamfront",
        description="Plugin-based visual SLAM front end: run and replay recipes, inspect, compare and recover logs, list plugins, evaluate.",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="show the version and exit")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, help="what to do")
    given = _command_in(argv) if argv is not None else None
    modules = [COMMANDS[given]] if given else list(dict.fromkeys(COMMANDS.values()))
    for module in modules:
        importlib.import_module(f"slamfront.cli.{module}").add_parser(commands)
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The sub-command ``argv`` runs: its first word, when that is one (else the whole parser is built)."""
    return argv[0] if argv and argv[0] in COMMANDS else None


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    terminal = None
    if _command_in(arguments) not in QUIET_COMMANDS:
        import logging

        from slamfront.logcapture import TerminalHandler

        terminal = TerminalHandler()  # plugins' and slamfront's warnings, above the progress bar
        logging.getLogger().addHandler(terminal)
    try:  # parsing too: a Ctrl-C while the parser imports plugins is one line, not a traceback
        completing = "_ARGCOMPLETE" in os.environ
        parser = build_parser(None if completing else arguments)
        if completing:  # the shell asks for completions (see docs: shell completion)
            import argcomplete

            argcomplete.autocomplete(parser)
        args = parser.parse_args(arguments)
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
        import traceback

        traceback.print_exc()  # a plugin's (or slamfront's) bug: its author needs the traceback
        print(
            f"slamfront: error: the run failed {failure.where}: {type(exc).__name__}: {exc}; "
            f"the log written so far is finalised: {failure.log}",
            file=sys.stderr,
        )
        return 1
    finally:
        if terminal is not None:
            import logging

            logging.getLogger().removeHandler(terminal)


if __name__ == "__main__":
    sys.exit(main())
