"""The three levels of the hierarchical sequence detector (Rodrigues 2019 §3.2), as pure logic.

Sequences of map places are written ``(first, last)`` in map positions (inclusive).
Nothing here reads the run: the detector (:mod:`.hierarchical_sequence`) feeds these
functions with arrays from the place map, so each level is tested on its own.

- Level 1 (§3.2.1, Alg. 2): the psi map places nearest to ``R(q_rho)``; each hit
  ``y_k`` with ``rho - 1`` places before it gives ``F_k = (y_k - rho + 1, y_k)``.
- Level 2 (§3.2.2, eq. 3.5-3.8, Alg. 3): the candidate nearest to Q place by place,
  then temporal consistency with the previous and the next iteration
  (:class:`TemporalConsistency`).
- Level 3 (§3.2.3, eq. 3.9-3.14, Alg. 4): expand to frames, pad, template matching,
  the synthetic descriptor sequence, confidence (:func:`match_frames`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from slamfront.core.distances import pairwise, rowwise
from slamfront.core.sequences import alignment_costs

Sequence2 = tuple[int, int]
"""A sequence of map places ``(first, last)``, inclusive map positions."""

Branch = Literal["consistent", "validated_by_next", "rebuilt", "unresolved"]


# --- level 1 --------------------------------------------------------------------------------


def candidate_sequences(hits: np.ndarray, rho: int) -> list[Sequence2]:
    """F_k for each level-1 hit ``y_k`` (eq. 3.4); hits with fewer than rho - 1 places before them are dropped."""
    return [(int(y) - rho + 1, int(y)) for y in hits if int(y) >= rho - 1]


# --- level 2 --------------------------------------------------------------------------------


def sequence_costs(query_representatives: np.ndarray, candidate_representatives: np.ndarray, metric: str) -> np.ndarray:
    """Eq. 3.5 for every candidate: ``sum_j D(R(q_j), R(f_j^k))``.

    :param query_representatives: (rho, D).
    :param candidate_representatives: (K, rho, D), the candidates' place representatives in order.
    :returns: (K,) float64; K x rho distances are computed.
    """
    k, rho, dim = candidate_representatives.shape
    query = np.broadcast_to(query_representatives, (k, rho, dim)).reshape(k * rho, dim)
    per_place = rowwise(query, candidate_representatives.reshape(k * rho, dim), metric).reshape(k, rho)  # type: ignore[arg-type]
    return per_place.astype(np.float64).sum(axis=1)


def consistent(previous: Sequence2, current: Sequence2, alpha: int) -> bool:
    """Eq. 3.6 / 3.7: ``|I(f_rho of previous) - I(f_1 of current)| < alpha``."""
    return abs(previous[1] - current[0]) < alpha


@dataclass(frozen=True)
class Dispatch:
    """A sequence sent to level 3 for the query sequence of ``iteration``.

    ``branch`` says why: consistent with the previous iteration; validated by the next
    one after waiting; rebuilt from the previous processed sequence plus the rho places
    after it (Alg. 3 lines 11-13); or ``unresolved`` when it had to be rebuilt but there
    was nothing to rebuild from (``sequence`` is None: no answer). ``synthetic`` says
    whether level 3 may try the synthetic descriptor sequence (not after validation by
    the next iteration, §3.2.3).
    """

    iteration: int
    sequence: Sequence2 | None
    branch: Branch
    synthetic: bool


class TemporalConsistency:
    """Level 2's bookkeeping across iterations (Alg. 3).

    :param rho: places per sequence; a rebuilt sequence is the last ``rho`` places of
        the previous processed sequence followed by the ``rho`` places after it (its
        end clipped to the map).
    :param alpha: the consistency threshold of eq. 3.6.
    """

    def __init__(self, rho: int, alpha: int) -> None:
        self.rho = rho
        self.alpha = alpha
        self.previous: Sequence2 | None = None
        """F^{*,i-1}: the best sequence of the last iteration (waiting or processed)."""
        self.waiting: tuple[int, Sequence2] | None = None
        """(iteration, sequence) waiting for the next iteration to validate it."""
        self.processed: Sequence2 | None = None
        """The last sequence sent to level 3 (what a rebuild starts from)."""

    def step(self, iteration: int, best: Sequence2 | None, n_map_places: int) -> list[Dispatch]:
        """Take iteration ``iteration``'s best candidate (None: level 1 found none) and say what goes to level 3."""
        out: list[Dispatch] = []
        if best is not None and self.previous is not None and consistent(self.previous, best, self.alpha):
            if self.waiting is not None:
                out.append(self._send(self.waiting[0], self.waiting[1], "validated_by_next", synthetic=False))
            out.append(self._send(iteration, best, "consistent", synthetic=True))
            self.waiting = None
        else:
            if self.waiting is not None:  # inconsistent with both neighbours: rebuild it
                out.append(self._rebuild(self.waiting[0], n_map_places))
            self.waiting = (iteration, best) if best is not None else None
        self.previous = best
        return out

    def finish(self, n_map_places: int) -> list[Dispatch]:
        """End of the traversal: a waiting sequence has no next iteration to validate it, so it is rebuilt."""
        if self.waiting is None:
            return []
        dispatch = self._rebuild(self.waiting[0], n_map_places)
        self.waiting = None
        return [dispatch]

    def _send(self, iteration: int, sequence: Sequence2, branch: Branch, synthetic: bool) -> Dispatch:
        self.processed = sequence
        return Dispatch(iteration, sequence, branch, synthetic)

    def _rebuild(self, iteration: int, n_map_places: int) -> Dispatch:
        if self.processed is None:
            return Dispatch(iteration, None, "unresolved", synthetic=False)
        first = max(self.processed[0], self.processed[1] - self.rho + 1)
        last = min(self.processed[1] + self.rho, n_map_places - 1)
        return self._send(iteration, (first, last), "rebuilt", synthetic=True)


# --- level 3 --------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameMatch:
    """Level 3's answer for one query sequence.

    ``aligned[k]`` is the map-frame position matched to query frame k (all -1 when
    there is no answer, with ``reason``). ``cost`` is the summed distance of the chosen
    alignment; ``mean_distance`` is v of eq. 3.14 over the informative query frames;
    ``n_distances`` counts the descriptor distances computed.
    """

    aligned: np.ndarray
    cost: float
    mean_distance: float
    template_offset: int
    template_cost: float
    synthetic_cost: float
    used_synthetic: bool
    padded_places: int
    reason: str = ""
    n_distances: int = 0


def expand_with_padding(
    sequence: Sequence2, offsets: np.ndarray, needed: int
) -> tuple[int, int, int] | None:
    """F-bar of a place sequence, grown to at least ``needed`` frames (§3.2.3, Fig. 3.4a).

    :param offsets: (P + 1,) map-frame offsets of the map places (place p covers
        ``offsets[p]:offsets[p + 1]``).
    :returns: ``(start, stop, padded places)`` in map-frame positions, adding one place
        before and one after per step where they exist; None when the whole map is
        shorter than ``needed``.
    """
    first, last = sequence
    n_places = len(offsets) - 1
    padded = 0
    while offsets[last + 1] - offsets[first] < needed:
        grew = False
        if first > 0:
            first, grew, padded = first - 1, True, padded + 1
        if last < n_places - 1:
            last, grew, padded = last + 1, True, padded + 1
        if not grew:
            return None
    return int(offsets[first]), int(offsets[last + 1]), padded


def match_frames(
    query: np.ndarray,
    informative: np.ndarray,
    sequence: Sequence2,
    offsets: np.ndarray,
    map_vectors: Callable[[int, int], np.ndarray],
    metric: str,
    previous_last: int | None,
    synthetic: bool,
) -> FrameMatch:
    """Level 3: align the query frames with the map frames of ``sequence``.

    :param query: (n, D) Q-bar, the descriptors of the query sequence's frames.
    :param informative: (n,) bool, query frames that are not featureless; only they
        count in the confidence (a featureless frame gets no answer anyway).
    :param map_vectors: ``(start, stop) -> (stop - start, D)`` map-frame descriptors.
    :param previous_last: map-frame position of the last frame matched by the previous
        level-3 call (None: none), the start of the synthetic descriptor sequence.
    :param synthetic: whether to try the synthetic descriptor sequence (eq. 3.12-3.13).
    """
    n = len(query)
    n_map_frames = int(offsets[-1])
    none = np.full(n, -1, dtype=np.int64)
    span = expand_with_padding(sequence, offsets, n)
    if span is None:
        return FrameMatch(none, np.nan, np.nan, -1, np.nan, np.nan, False, 0,
                          reason=f"the map has fewer than the {n} frames of the query sequence")
    start, stop, padded = span
    distances = pairwise(query, map_vectors(start, stop), metric)  # type: ignore[arg-type]
    costs = alignment_costs(distances)
    offset = int(np.argmin(costs))
    template_cost = float(costs[offset])
    aligned = start + offset + np.arange(n, dtype=np.int64)
    per_frame = distances[np.arange(n), offset + np.arange(n)].astype(np.float64)
    synthetic_cost = np.nan
    used = False
    computed = distances.size
    if synthetic and previous_last is not None and previous_last + 1 + n <= n_map_frames:
        continuation = previous_last + 1 + np.arange(n, dtype=np.int64)
        synthetic_per_frame = rowwise(query, map_vectors(previous_last + 1, previous_last + 1 + n), metric).astype(np.float64)  # type: ignore[arg-type]
        computed += n
        synthetic_cost = float(synthetic_per_frame.sum())
        if synthetic_cost <= template_cost:  # eq. 3.13
            aligned, per_frame, used = continuation, synthetic_per_frame, True
    cost = float(per_frame.sum())
    mean = float(per_frame[informative].mean()) if informative.any() else np.nan
    return FrameMatch(aligned, cost, mean, offset, template_cost, synthetic_cost, used, padded, n_distances=computed)
