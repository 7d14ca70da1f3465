"""Stopping a run with SIGINT (Ctrl-C) or SIGTERM without damaging its log.

Python raises ``KeyboardInterrupt`` wherever the main thread happens to be when the
signal arrives, which may be half-way through appending a record to the MCAP file; the
log would then be finalised around a half-written record. :class:`Interrupts` turns both
signals into :class:`RunInterrupted` and holds it back while a *critical section* (a
log write) is running, raising it as soon as the section ends.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType, TracebackType
from typing import Any

HANDLED = (signal.SIGINT, signal.SIGTERM)


class RunInterrupted(KeyboardInterrupt):
    """The run was stopped by SIGINT or SIGTERM."""


class Interrupts:
    """While entered, SIGINT and SIGTERM raise :class:`RunInterrupted`, never inside
    :meth:`critical`. Signal handlers can only be installed from the main thread;
    elsewhere the previous behaviour is kept and :meth:`critical` is a plain block.
    """

    def __init__(self) -> None:
        self._depth = 0
        self._pending: str | None = None
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if self._depth > 0:
            self._pending = name  # raised when the critical section ends
            return
        raise RunInterrupted(f"signal {name}")

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            for signum in HANDLED:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous.clear()

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """A block a signal must not cut in two; a signal received meanwhile is raised after it."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
            if self._depth == 0 and self._pending is not None:
                name, self._pending = self._pending, None
                raise RunInterrupted(f"signal {name}")
