"""Plugins log with Python's :mod:`logging`; a run keeps their records in its ``/log`` topic.

A plugin module takes a logger the usual way (``logger = logging.getLogger(__name__)``)
and calls ``logger.info(...)``, ``logger.warning(...)``. While a run lasts,
:class:`RunLogCapture` listens on the loggers of the packages the run's plugins come
from (and on ``slamfront``'s own), buffers each record at the recipe's ``log.level`` and
above, and the runtime writes them to ``/log`` as Foxglove ``Log`` messages between
stage calls, stamped with the current frame's time. Writing between stage calls, never
from inside ``emit``, keeps the MCAP writer single-threaded even when a plugin logs from
a worker thread, and keeps the records in step with the frame that caused them.

Warnings and errors also reach the terminal: the CLI installs :class:`TerminalHandler`
on the root logger (records propagate to it as usual), which writes above a progress bar.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable
from types import TracebackType
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the command line imports this module for every command: keep it light
    from slamfront.mcaplog.writer import RunLogWriter

_FOXGLOVE_LEVEL = {
    logging.DEBUG: "debug", logging.INFO: "info", logging.WARNING: "warning", logging.ERROR: "error",
    logging.CRITICAL: "fatal",
}


def foxglove_level(levelno: int) -> str:
    """The Foxglove ``Log`` level of a :mod:`logging` level number (custom levels round down)."""
    return _FOXGLOVE_LEVEL[max((n for n in _FOXGLOVE_LEVEL if n <= levelno), default=logging.DEBUG)]


class _Buffer(logging.Handler):
    """Keeps records until the runtime writes them; ``handle`` holds the handler's lock."""

    def __init__(self, level: int) -> None:
        super().__init__(level)
        self.records: list[tuple[logging.LogRecord, str]] = []
        self.setFormatter(logging.Formatter("%(message)s"))  # adds the traceback of logger.exception

    def emit(self, record: logging.LogRecord) -> None:
        # formatted now: the arguments may be objects the plugin changes after logging
        self.records.append((record, self.format(record)))

    def take(self) -> list[tuple[logging.LogRecord, str]]:
        with self.lock:  # type: ignore[union-attr] # created by logging.Handler.__init__
            taken, self.records = self.records, []
        return taken


class RunLogCapture:
    """While a run lasts, collect the records of ``packages``' loggers for its ``/log``.

    :param packages: top-level logger names to listen on (``slamfront_plugins``, a
        third-party plugin package, ``slamfront``).
    :param level: the lowest level recorded (``debug``, ``info``, ``warning``, ``error``); loggers set higher are lowered for the run
        and restored after it.
    """

    def __init__(self, packages: Iterable[str], level: str = "info") -> None:
        self.level = logging.getLevelName(level.upper())
        self.loggers = [logging.getLogger(name) for name in sorted(set(packages))]
        self._buffer = _Buffer(self.level)
        self._saved_levels: list[int] = []

    def __enter__(self) -> RunLogCapture:
        self._saved_levels = [logger.level for logger in self.loggers]
        for logger in self.loggers:
            logger.addHandler(self._buffer)
            if logger.getEffectiveLevel() > self.level:
                logger.setLevel(self.level)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for logger, saved in zip(self.loggers, self._saved_levels):
            logger.removeHandler(self._buffer)
            logger.setLevel(saved)

    def flush(self, log: RunLogWriter, stamp_ns: int) -> int:
        """Write the records kept so far to ``/log`` at ``stamp_ns``; returns how many."""
        records = self._buffer.take()
        if not records:  # the usual case: called after every stage of every frame
            return 0
        from slamfront.mcaplog import foxglove
        from slamfront.mcaplog.topics import LOG_TOPIC

        for record, text in records:
            line = foxglove.log_line(
                text, stamp_ns, foxglove_level(record.levelno), record.name,
                file=record.filename, line=record.lineno,
            )
            log.write_foxglove(LOG_TOPIC, line, stamp_ns)
        return len(records)


class TerminalHandler(logging.Handler):
    """Warnings and errors on stderr as ``slamfront: warning: ...``, above any progress bar."""

    def __init__(self, level: int = logging.WARNING) -> None:
        super().__init__(level)
        self.setFormatter(logging.Formatter("%(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            origin = "" if record.name.split(".")[0] == "slamfront" else f"{record.name}: "
            text = f"slamfront: {record.levelname.lower()}: {origin}{self.format(record)}"
            from tqdm import tqdm  # imported on the first warning: the command line starts faster

            tqdm.write(text, file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging's contract: a handler never raises
            self.handleError(record)
