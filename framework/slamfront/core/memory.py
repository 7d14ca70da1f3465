"""RTAB-Map memory management (Labbé & Michaud 2013), as Wang et al. 2017 uses it.

Places live in one of three memories:

- **STM** (short-term): the ``stm_size`` newest places. Not searched, so an image is
  never "closing a loop" with the places it just left.
- **WM** (working): the places loop closure searches. A place enters it when it
  leaves the STM.
- **LTM** (long-term): places transferred out of WM; not searched, but kept, and
  *retrieved* back into WM when a neighbour of theirs becomes the best loop hypothesis.

Each place has a *weight*: how many images were merged into it because they were too
similar to it (Wang et al. 2017's T_sim filter; RTAB-Map's rehearsal). When a loop is
accepted, the newer place of the pair takes the older one's weight and the older one
drops to 0 (``Memory::addLink``): the place the robot is at now carries the location's
history.

**Transfer** (``Memory::forget`` for an incremental vocabulary). When an image took
longer than the time budget, places move from WM to LTM one at a time, in transfer
order, until at least as many words have left the nearest-word search as arrived in it
during the image (the image's new words and those of places retrieved from LTM).
That rule alone keeps the searched vocabulary, which is what the time grows with, from
growing while the budget is exceeded, but does not bring it back under: the time
hovers at the budget, half the images over it. RTAB-Map means the budget as a limit
(Labbé & Michaud 2013: the time to process new observations is kept under a fixed
limit), so a caller that can *predict* the next image's time from WM's size
(``predict``, e.g. a :class:`LinearTimeModel` of searched words and WM places) also
transfers when the prediction is over the budget, before the image is, and places keep
leaving until the prediction is within it.
``forget_places: true`` also transfers at least one place more than entered WM during
the image (RTAB-Map's rule without an incremental vocabulary). A place cap
(``max_working_memory``) transfers in the same order until WM holds no more places
than the cap: a deterministic limit for reproducible experiments.

Transfer order (``Memory::getRemovableSignatures``): lowest weight first, then the
place that entered WM longest ago, then the oldest id. Never transferred:

- places kept *immune* for the step (the best hypothesis and its neighbours within the
  retrieval radius, what was just retrieved);
- the *recent* places: the newer place of the last accepted loop and the WM places
  created after it, while they are more than one and fewer than ``recent_ratio`` of WM
  (RTAB-Map's ``Mem/RecentWmRatio``, 0.2): after a loop closure the robot is likely to
  keep following the old path, and the places it laid down since are what connects it.

Bound: with a time that grows with the searched words, an image over budget leaves no
more words searched than it found, and one within budget adds at most its arrivals, so
the words searched never exceed those that fit the budget plus one image's arrivals
(provided WM holds enough places that are not immune or recent). With ``predict`` every
image leaves WM predicted within the budget, so an image goes over only when the
prediction was wrong.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
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
    recent_ratio: float = 0.2
    """Places created since the last accepted loop are not transferred while they are fewer than this share of WM."""
    forget_places: bool = False
    """Over budget, also transfer at least one place more than entered WM (not only as many words as arrived)."""

    def __post_init__(self) -> None:
        if self.stm_size < 0 or self.max_working_memory < 0 or self.max_retrieved < 0 or self.retrieval_radius < 0:
            raise CoreError("memory sizes must be >= 0")
        if self.time_budget_s < 0:
            raise CoreError("the time budget must be >= 0")
        if not 0.0 <= self.recent_ratio <= 1.0:
            raise CoreError(f"recent_ratio must be in [0, 1], got {self.recent_ratio}")


@dataclass(frozen=True)
class LinearTimeModel:
    """A deterministic stand-in for an image's processing time, for reproducible budgets.

    ``seconds = base_s + comparison_s * features * words + place_s * places``: the
    nearest-word search compares every feature with every searched word, and the
    similarity and Bayes filter touch every WM place. The coefficients are fitted to
    measured times (``benchmarks/bench_bow_bayes.py``), so a budget in these seconds
    means about the same as one on the clock, but the same run always gives the same
    transfers, whatever else the machine is doing.
    """

    base_s: float = 0.0
    comparison_s: float = 0.0
    place_s: float = 0.0

    def __post_init__(self) -> None:
        if min(self.base_s, self.comparison_s, self.place_s) < 0:
            raise CoreError("time model coefficients must be >= 0")

    def seconds(self, features: float, words: float, places: float) -> float:
        """Modelled seconds of an image with ``features`` features, ``words`` searched words, ``places`` in WM."""
        return self.base_s + self.comparison_s * features * words + self.place_s * places

    @classmethod
    def fit(
        cls, features: np.ndarray, words: np.ndarray, places: np.ndarray, seconds: np.ndarray
    ) -> tuple[LinearTimeModel, float]:
        """Non-negative least squares of measured ``seconds`` on (1, features x words, places).

        All arguments are (N,) arrays, one entry per image. Returns the model and its R^2
        (NaN when the seconds do not vary). Columns are scaled to unit maximum first: the
        products are ~1e6 times the counts of places, which would otherwise decide the
        solver's tolerance.
        """
        x = np.column_stack([np.ones(len(seconds)), np.asarray(features, float) * np.asarray(words, float),
                             np.asarray(places, float)])
        y = np.asarray(seconds, float)
        scale = np.abs(x).max(axis=0)
        scale[scale == 0] = 1.0
        from scipy.optimize import nnls  # ~0.5 s to import: only when a cost model is fitted

        coefficients, _ = nnls(x / scale, y)
        coefficients = coefficients / scale
        residual = y - x @ coefficients
        spread = float(((y - y.mean()) ** 2).sum())
        r2 = 1.0 - float(residual @ residual) / spread if spread > 0 else float("nan")
        return cls(*(float(c) for c in coefficients)), r2


class MemoryManager:
    """Which memory each place is in, and the weights and ages that order transfers."""

    def __init__(self, parameters: MemoryParameters | None = None) -> None:
        self.parameters = parameters or MemoryParameters()
        self._stm: deque[int] = deque()
        self._wm: dict[int, int] = {}  # place -> when it (last) entered WM, a step count
        self._ltm: set[int] = set()
        self._weights: dict[int, int] = {}
        self._entries = 0
        self._last_loop = -1  # the newer place of the last accepted loop (RTAB-Map's last global closure)

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

    @property
    def last_loop(self) -> int:
        """The newer place of the last accepted loop, -1 before the first."""
        return self._last_loop

    # --- changes ------------------------------------------------------------------

    def add(self, place: int) -> list[int]:
        """A new place enters the STM; returns the places that left it for WM."""
        if place in self._weights:
            raise CoreError(f"place {place} is already in memory")
        self._weights[place] = 0
        self._stm.append(place)
        moved = []
        while len(self._stm) > self.parameters.stm_size:
            moved.append(self._enter_working(self._stm.popleft()))
        return moved

    def flush(self) -> list[int]:
        """Move every STM place to WM (the reference traversal is over)."""
        moved = [self._enter_working(place) for place in self._stm]
        self._stm.clear()
        return moved

    def merge(self, place: int) -> None:
        """An image too similar to ``place`` was merged into it: its weight grows."""
        self._weights[place] += 1

    def close_loop(self, current: int, matched: int) -> None:
        """An accepted loop between ``current`` and ``matched``: the newer takes the older's weight.

        RTAB-Map's ``Memory::addLink`` for a global loop closure; the newer place also
        starts the recent stretch that :meth:`transfer_order` protects.
        """
        if current == matched:
            return
        newer, older = max(current, matched), min(current, matched)
        self._weights[newer] += self._weights[older]
        self._weights[older] = 0
        self._last_loop = newer

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
            self._enter_working(place)
        return found

    def immune_around(self, centre: int) -> set[int]:
        """The best hypothesis and its neighbours within the radius: kept in WM this step."""
        radius = self.parameters.retrieval_radius
        return {place for place in range(centre - radius, centre + radius + 1) if place in self._wm}

    def recent(self) -> set[int]:
        """WM places protected as recent: the last loop's newer place and those created after it.

        The stretch is protected only while it holds more than one place and fewer than
        ``recent_ratio`` of WM (RTAB-Map's ``getRemovableSignatures``); the loop's place
        itself always is, once it has left the STM.
        """
        if self._last_loop not in self._wm:
            return set()
        stretch = {place for place in self._wm if place >= self._last_loop}
        if 1 < len(stretch) < self.parameters.recent_ratio * len(self._wm):
            return stretch
        return {self._last_loop}

    def transfer_order(self, immune: set[int]) -> list[int]:
        """The WM places that may be transferred, first to go first: lowest weight, longest in WM, oldest."""
        protected = immune | self.recent()
        places = np.fromiter(self._wm.keys(), dtype=np.int64, count=len(self._wm))
        entered = np.fromiter(self._wm.values(), dtype=np.int64, count=len(self._wm))
        weights = np.fromiter(map(self._weights.__getitem__, self._wm), dtype=np.int64, count=len(self._wm))
        # one sort in NumPy (keys last to first): every frame over budget asks for it
        order = places[np.lexsort((places, entered, weights))].tolist()
        return [place for place in order if place not in protected]

    def transfer(
        self, elapsed_s: float, words_arrived: int, immune: set[int], release: Callable[[int], int],
        places_entered: int = 0, predict: Callable[[], float] | None = None,
    ) -> list[int]:
        """Move places from WM to LTM if this image (or the next, predicted) is over budget or WM is over its cap.

        :param elapsed_s: how long the image took (measured, or modelled).
        :param words_arrived: words that joined the nearest-word search during the image.
        :param immune: places that must stay this step.
        :param release: called with each transferred place as it goes; returns how many
            words left the search with it (those no place still in STM or WM uses).
        :param places_entered: places that entered WM during the image (from STM or LTM);
            with ``forget_places``, at least one more leaves.
        :param predict: the predicted seconds of the next image with WM as it is now,
            called again after each transfer: places also leave when it is over the
            budget, until it is within it (or nothing transferable is left).
        :returns: the transferred places, in transfer order.
        """
        p = self.parameters
        bounded = p.time_budget_s > 0
        over_budget = bounded and elapsed_s > p.time_budget_s

        def predicted_within() -> bool:
            return not bounded or predict is None or predict() <= p.time_budget_s

        over_cap = p.max_working_memory > 0 and len(self._wm) > p.max_working_memory
        if not over_budget and not over_cap and predicted_within():
            return []
        transferred: list[int] = []
        words_left = 0
        places = places_entered + 1 if p.forget_places else 0
        for place in self.transfer_order(immune):
            rule_done = not over_budget or (words_left >= words_arrived and len(transferred) >= places)
            budget_done = rule_done and predicted_within()
            cap_done = p.max_working_memory == 0 or len(self._wm) <= p.max_working_memory
            if budget_done and cap_done:
                break
            del self._wm[place]
            self._ltm.add(place)
            transferred.append(place)
            words_left += release(place)
        return transferred

    def _enter_working(self, place: int) -> int:
        self._entries += 1
        self._wm[place] = self._entries
        return place
