"""Pairing streams by nearest timestamp, one message at a time, in bounded memory.

A recording interleaves topics in the order messages arrived. Each *primary* message
(an image) needs, from every *partner* stream (depth, pose), the message nearest to it
in time within a tolerance; a primary without one is dropped. :class:`StreamPairing`
decides a primary as soon as it can be sure (a stream's own stamps increase, so a later
message cannot be nearer than one already seen as far after the primary): at once when a
partner has its very stamp, else when every partner stream has gone past it far enough,
or has ended. Messages that can no longer be anyone's
partner are forgotten, so memory holds only the few messages around the present.

A primary still undecided ``patience_ns`` of arrival time after it came (a partner
stream that stopped) is decided with what has been seen, so memory stays bounded even
then. Times are integer nanoseconds.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from slamfront.core.errors import CoreError


@dataclass
class PartnerStream:
    """The recent messages of one partner stream, sorted by stamp."""

    stamps: list[int] = field(default_factory=list)
    items: list[Any] = field(default_factory=list)
    latest: int | None = None
    ended: bool = False

    def add(self, stamp: int, item: Any) -> None:
        at = bisect.bisect_right(self.stamps, stamp)
        self.stamps.insert(at, stamp)
        self.items.insert(at, item)
        self.latest = stamp if self.latest is None else max(self.latest, stamp)

    def settled(self, stamp: int, tolerance: int) -> bool:
        """No later message can be nearer to ``stamp`` than what is here: the stream has
        ended, or shown a message at least as far after ``stamp`` as the nearest one so far
        is from it (at once for a partner with the very same stamp), or past the tolerance."""
        if self.ended:
            return True
        if self.latest is None:
            return False
        best = self.nearest(stamp, tolerance)
        return self.latest > stamp + tolerance or (best is not None and self.latest >= stamp + abs(best[0] - stamp))

    def nearest(self, stamp: int, tolerance: int) -> tuple[int, Any] | None:
        """(stamp, item) nearest to ``stamp`` within ``tolerance`` (the earlier one on a tie)."""
        at = bisect.bisect_left(self.stamps, stamp)
        best: tuple[int, Any] | None = None
        for i in (at - 1, at):
            if 0 <= i < len(self.stamps):
                gap = abs(self.stamps[i] - stamp)
                if gap <= tolerance and (best is None or gap < abs(best[0] - stamp)):
                    best = (self.stamps[i], self.items[i])
        return best

    def forget_before(self, stamp: int) -> None:
        """Drop messages stamped before ``stamp`` (keeping the last one of them: it may
        still be nearest to a primary stamped just after)."""
        cut = max(bisect.bisect_left(self.stamps, stamp) - 1, 0)
        del self.stamps[:cut], self.items[:cut]


@dataclass(frozen=True)
class Paired:
    """A primary message and the partner nearest to it in each stream (None: none within tolerance)."""

    stamp: int
    item: Any
    partners: dict[str, tuple[int, Any] | None]

    @property
    def complete(self) -> bool:
        return all(p is not None for p in self.partners.values())


class StreamPairing:
    """Nearest-timestamp pairing of a primary stream with partner streams.

    :param partners: names of the partner streams.
    :param tolerance_ns: the largest stamp difference a pair may have.
    :param patience_ns: decide a primary at the latest this long (arrival time) after it came.
    """

    def __init__(self, partners: Sequence[str], tolerance_ns: int, patience_ns: int = 2_000_000_000) -> None:
        if tolerance_ns < 0:
            raise CoreError(f"the pairing tolerance must not be negative, got {tolerance_ns} ns")
        self.tolerance = int(tolerance_ns)
        self.patience = int(patience_ns)
        self.streams = {name: PartnerStream() for name in partners}
        self._pending: deque[tuple[int, int, Any]] = deque()  # (stamp, arrival, item)

    def __len__(self) -> int:
        """Primaries waiting for a decision."""
        return len(self._pending)

    def add_primary(self, stamp: int, arrival: int, item: Any) -> list[Paired]:
        self._pending.append((stamp, arrival, item))
        return self._decide(arrival)

    def add_partner(self, name: str, stamp: int, arrival: int, item: Any) -> list[Paired]:
        self.streams[name].add(stamp, item)
        return self._decide(arrival)

    def finish(self) -> list[Paired]:
        """Every partner stream has ended: decide all pending primaries."""
        for stream in self.streams.values():
            stream.ended = True
        return self._decide(None)

    def _decide(self, now: int | None) -> list[Paired]:
        decided = []
        while self._pending:
            stamp, arrival, item = self._pending[0]
            waited_enough = now is not None and now - arrival >= self.patience
            if not waited_enough and not all(s.settled(stamp, self.tolerance) for s in self.streams.values()):
                break
            self._pending.popleft()
            decided.append(Paired(stamp, item, {
                name: stream.nearest(stamp, self.tolerance) for name, stream in self.streams.items()
            }))
        if decided:
            # what no pending (or later) primary can pair with any more
            oldest = min((s for s, _, _ in self._pending), default=decided[-1].stamp)
            for stream in self.streams.values():
                stream.forget_before(oldest - self.tolerance)
        elif not self._pending:
            # nothing waits: keep what a primary stamped up to `patience` in the past could use
            for stream in self.streams.values():
                if stream.latest is not None:
                    stream.forget_before(stream.latest - self.patience - self.tolerance)
        return decided
