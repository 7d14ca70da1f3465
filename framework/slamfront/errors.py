"""Errors a user can cause and fix.

The CLI turns every :class:`SlamfrontError` into one line on stderr and exit code 2.
Anything else is a bug in slamfront or in a plugin and keeps its traceback. Either way,
when the error stops a run whose log was opened, the exception carries a
:class:`RunFailure` (:func:`run_failure_of`) so the message can say where the log is.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple


class SlamfrontError(Exception):
    """A user-facing error: the message names the file and the field at fault."""


class RecipeError(SlamfrontError):
    """A recipe (or a ``--set`` override) is missing, malformed or invalid."""


class PluginError(SlamfrontError):
    """A plugin is unknown, badly declared, or incompatible with the rest of the recipe."""


class DataError(SlamfrontError):
    """Input data (images, depth, ground truth, pose graphs) is missing or unreadable."""


class LogError(SlamfrontError):
    """An MCAP log is missing, truncated or not a slamfront log."""


class RunFailure(NamedTuple):  # not a dataclass: `import dataclasses` costs every command ~10 ms
    """Where a failed run was, and the log it leaves (finalised and readable, but partial)."""

    log: Path
    where: str
    """What the run was doing: ``in the descriptor plugin 'x' at frame 12``."""


_RUN_FAILURE = "slamfront_run_failure"  # the attribute an exception carries its RunFailure in


def note_run_failure(exc: BaseException, log: Path, where: str) -> None:
    """Record on ``exc`` that it stopped a run writing ``log`` (the innermost run wins)."""
    if run_failure_of(exc) is None:
        setattr(exc, _RUN_FAILURE, RunFailure(log, where))


def run_failure_of(exc: BaseException) -> RunFailure | None:
    """The :class:`RunFailure` ``exc`` carries, if it stopped a run."""
    return getattr(exc, _RUN_FAILURE, None)
