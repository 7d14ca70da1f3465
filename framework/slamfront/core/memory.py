"""RTAB-Map memory management (Labbé & Michaud 2013), as Wang et al. 2017 uses it.

Places live in one of three memories:

- **STM** (short-term): the ``stm_size`` newest places. Not searched, so an image is
  never "closing a loop" with the places it just left.
- **WM** (working): the places loop closure searches. A place enters it when it
  leaves the STM.
- **LTM** (long-term): places transferred out of WM; not searched, but kept, and
  *retrieved* back into WM when a neighbour of theirs becomes the best loop hypothesis.

Each place has a *weight*: how many images were merged into it because they were too
similar to it (Wang et al. 2017's T_sim filter; RTAB-Map's rehearsal). When the processing time
of an image exceeds the time budget, the **lowest-weighted, then oldest** places are
transferred from WM to LTM: one more than entered WM during that image
(``Memory::forget``: "remove one more than total added during the iteration"), so WM
shrinks while the budget is exceeded and its size settles where an image takes about
the budget. Places kept "immune" for the step (the best hypothesis, its neighbours,
what was just retrieved) are never transferred.

Bound: if an image's time is ``base + per_place * |WM|``, WM at search time never
exceeds :func:`working_memory_bound` (``N* + 1 + max_retrieved``, N* the largest WM
within budget), provided WM holds more places than the immune ones.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from slamfront.core.errors import CoreError


@dataclass(frozen=True)
class MemoryParameters:
    """Sizes and limits of the memories."""

    stm_size: int = 10
    """Newest places kept out of the search."""
    time_budget_s: float = 0.7
    """T_time: transfer places out of WM when an image took longer (0: no limit)."""
    max_working_memory: int = 0
    """Also transfer when WM holds more places than this (0: no cap; deterministic)."""
    max_retrieved: int = 2
    """At most this many places brought back from LTM per image."""
    retrieval_radius: int = 3
    """Places within this many ids of the best hypothesis are retrieved and immune."""

    def __post_init__(self) -> None:
        if self.stm_size < 0 or self.max_working_memory < 0 or self.max_retrieved < 0 or self.retrieval_radius < 0:
            raise CoreError("memory sizes must be >= 0")
        if self.time_budget_s < 0:
            raise CoreError("the time budget must be >= 0")


def working_memory_bound(time_budget_s: float, base_s: float, per_place_s: float, max_retrieved: int) -> int:
    """The largest WM size at search time under the cost model ``base + per_place * |WM|``.

    With ``N* = floor((budget - base) / per_place)``, the largest WM searched within
    budget: a step at or under N* adds at most one place from STM and ``max_retrieved``
    from LTM; a step over N* transfers one more than it added. So WM at search time
    stays at most ``N* + 1 + max_retrieved``.
    """
    if per_place_s <= 0 or time_budget_s <= 0:
        raise CoreError("the bound needs a positive time budget and cost per place")
    within = max(0, math.floor((time_budget_s - base_s) / per_place_s + 1e-9))  # 0.65 / 0.002 is 324.99...
    return within + 1 + max_retrieved


class MemoryManager:
    """Which memory each place is in, and the weights that decide transfers."""

    def __init__(self, parameters: MemoryParameters | None = None) -> None:
        self.parameters = parameters or MemoryParameters()
        self._stm: deque[int] = deque()
        self._wm: set[int] = set()
        self._ltm: set[int] = set()
        self._weights: dict[int, int] = {}

    # --- state --------------------------------------------------------------------

    @property
    def stm(self) -> list[int]:
        return list(self._stm)

    @property
    def n_stm(self) -> int:
        return len(self._stm)

    @property
    def n_wm(self) -> int:
        return len(self._wm)

    @property
    def n_ltm(self) -> int:
        return len(self._ltm)

    def working(self) -> np.ndarray:
        """(M,) int64 the WM place ids, sorted: the loop hypotheses."""
        return np.array(sorted(self._wm), dtype=np.int64)

    def in_working(self, place: int) -> bool:
        return place in self._wm

    def in_long_term(self, place: int) -> bool:
        return place in self._ltm

    def weight(self, place: int) -> int:
        return self._weights[place]

    # --- changes ------------------------------------------------------------------

    def add(self, place: int) -> list[int]:
        """A new place enters the STM; returns the places that left it for WM."""
        if place in self._weights:
            raise CoreError(f"place {place} is already in memory")
        self._weights[place] = 0
        self._stm.append(place)
        moved = []
        while len(self._stm) > self.parameters.stm_size:
            oldest = self._stm.popleft()
            self._wm.add(oldest)
            moved.append(oldest)
        return moved

    def flush(self) -> list[int]:
        """Move every STM place to WM (the reference traversal is over)."""
        moved = list(self._stm)
        self._wm.update(moved)
        self._stm.clear()
        return moved

    def merge(self, place: int) -> None:
        """An image too similar to ``place`` was merged into it: its weight grows."""
        self._weights[place] += 1

    def retrieve(self, centre: int) -> list[int]:
        """Bring LTM neighbours of ``centre`` (ids within the radius, nearest first) back to WM."""
        radius, limit = self.parameters.retrieval_radius, self.parameters.max_retrieved
        found = []
        for distance in range(1, radius + 1):
            for place in (centre - distance, centre + distance):
                if len(found) < limit and place in self._ltm:
                    found.append(place)
        for place in found:
            self._ltm.discard(place)
            self._wm.add(place)
        return found

    def immune_around(self, centre: int) -> set[int]:
        """The best hypothesis and its neighbours within the radius: kept in WM this step."""
        radius = self.parameters.retrieval_radius
        return {place for place in range(centre - radius, centre + radius + 1) if place in self._wm}

    def transfer(self, elapsed_s: float, entered: int, immune: set[int]) -> list[int]:
        """Move places from WM to LTM if this image was over budget or WM is over its cap.

        :param elapsed_s: how long the image took.
        :param entered: places that entered WM during the image (from STM or LTM).
        :param immune: places that must stay.
        :returns: the transferred places, in transfer order.
        """
        p = self.parameters
        count = 0
        if p.time_budget_s > 0 and elapsed_s > p.time_budget_s:
            count = entered + 1
        if p.max_working_memory > 0:
            count = max(count, len(self._wm) - p.max_working_memory)
        if count <= 0:
            return []
        candidates = sorted((self._weights[place], place) for place in self._wm if place not in immune)
        chosen = [place for _, place in candidates[:count]]
        for place in chosen:
            self._wm.discard(place)
            self._ltm.add(place)
        return chosen
