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
"""A sequence of map places ``(first, last)``, inclusive map positions (first > last: run backwards)."""

Branch = Literal["consistent", "validated_by_next", "rebuilt", "unresolved"]


# --- level 1 --------------------------------------------------------------------------------


def candidate_sequences(hits: np.ndarray, rho: int) -> list[Sequence2]:
    """F_k for each level-1 hit ``y_k`` (eq. 3.4); hits with fewer than rho - 1 places before them are dropped."""
    return [(int(y) - rho + 1, int(y)) for y in hits if int(y) >= rho - 1]


def place_speeds(low: float, high: float, rho: int, reverse: bool) -> np.ndarray:
    """(S,) place speeds (map places per query place) from ``low`` to ``high`` in steps of
    ``1 / (rho - 1)`` (each step moves a sequence's first place by one place), speed 1 first,
    then the slower, the faster and (``reverse``) the same speeds backwards."""
    steps = max(rho - 1, 1)
    spans = np.arange(max(1, int(np.ceil(low * steps - 1e-9))), int(np.floor(high * steps + 1e-9)) + 1)
    forward = sorted((spans / steps).tolist(), key=lambda v: (abs(v - 1.0), v))
    return np.asarray(forward + ([-v for v in forward] if reverse else []), dtype=np.float64)


def candidate_paths(hits: np.ndarray, rho: int, speeds: np.ndarray, n_places: int) -> list[tuple[np.ndarray, float]]:
    """Eq. 3.4 at any place speed: for each hit ``y_k`` and speed ``s``, query place j pairs with
    map place ``y_k - round((rho - 1 - j) * s)`` (``s < 0``: the query runs the map backwards,
    its earlier places after ``y_k``); paths leaving ``0..n_places - 1`` are dropped. Speed 1
    gives :func:`candidate_sequences`' F_k. Returns ``(rho,) map places, speed`` pairs."""
    steps = np.arange(rho - 1, -1, -1, dtype=np.float64)
    out = []
    for y in hits.tolist():
        for speed in speeds.tolist():
            path = int(y) - np.floor(steps * speed + 0.5).astype(np.int64)
            if path.min() >= 0 and path.max() < n_places:
                out.append((path, float(speed)))
    return out


def path_costs(query_representatives: np.ndarray, map_representatives: Callable[[np.ndarray], np.ndarray],
               paths: np.ndarray, metric: str) -> tuple[np.ndarray, int]:
    """Eq. 3.5 along place paths: ``sum_j D(R(q_j), R(paths[k, j]))``, each distinct (j, place)
    pair computed once. Returns the (K,) costs and the number of distances computed."""
    k, rho = paths.shape
    keys = np.arange(rho)[None, :] * (int(paths.max()) + 1) + paths
    unique, inverse = np.unique(keys.ravel(), return_inverse=True)
    rows, places = np.divmod(unique, int(paths.max()) + 1)
    per_pair = rowwise(query_representatives[rows], map_representatives(places), metric)  # type: ignore[arg-type]
    return per_pair.astype(np.float64)[inverse].reshape(k, rho).sum(axis=1), len(unique)


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
        if self.processed[1] >= self.processed[0]:
            first = max(self.processed[0], self.processed[1] - self.rho + 1)
            last = min(self.processed[1] + self.rho, n_map_places - 1)
        else:  # a query running the map backwards goes on towards its start
            first = min(self.processed[0], self.processed[1] + self.rho - 1)
            last = max(self.processed[1] - self.rho, 0)
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
    speed: float | None = None,
    query_places: int = 1,
) -> FrameMatch:
    """Level 3: align the query frames with the map frames of ``sequence``.

    :param query: (n, D) Q-bar, the descriptors of the query sequence's frames.
    :param informative: (n,) bool, query frames that are not featureless; only they
        count in the confidence (a featureless frame gets no answer anyway).
    :param map_vectors: ``(start, stop) -> (stop - start, D)`` map-frame descriptors.
    :param previous_last: map-frame position of the last frame matched by the previous
        level-3 call (None: none), the start of the synthetic descriptor sequence.
    :param synthetic: whether to try the synthetic descriptor sequence (eq. 3.12-3.13).
    :param speed: None: Q-bar slid along F-bar frame by frame (the letter); else the
        sequence's place speed (map places per query place; negative: backwards), and Q-bar
        is slid along F-bar at the matching frame speed (:func:`_match_at_speed`), without
        the synthetic sequence (a place holds as many frames as the pace gave it, so place
        speed 1 need not be frame speed 1).
    :param query_places: places of Q (to turn the place speed into a frame speed).
    """
    if speed is not None:
        return _match_at_speed(query, informative, sequence, offsets, map_vectors, metric, speed, query_places)
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


def _match_at_speed(
    query: np.ndarray,
    informative: np.ndarray,
    sequence: Sequence2,
    offsets: np.ndarray,
    map_vectors: Callable[[int, int], np.ndarray],
    metric: str,
    speed: float,
    query_places: int,
) -> FrameMatch:
    """Level 3 for a sequence at place speed ``speed``: the frame speed is the place speed
    times the sequence's map frames per place over Q's query frames per place; Q-bar is laid
    along F-bar (padded to the frames that speed needs) on lines of that slope, and of that
    slope divided and multiplied by 1.25 and 1.5 (places differ in length), and at slope 1, backwards for a negative
    speed, at every offset; the lowest summed distance wins (eq. 3.10 on a sloped line)."""
    n = len(query)
    none = np.full(n, -1, dtype=np.int64)
    low, high = min(sequence), max(sequence)
    per_map_place = (int(offsets[high + 1]) - int(offsets[low])) / (high - low + 1)
    frame_speed = abs(speed) * per_map_place / max(n / max(query_places, 1), 1e-9)
    slopes = np.unique(np.append(frame_speed * np.asarray([1.0, 0.8, 1.25, 1 / 1.5, 1.5]), 1.0))
    needed = int(np.ceil(slopes.max() * (n - 1))) + 1
    span = expand_with_padding((low, high), offsets, needed)
    if span is None:
        return FrameMatch(none, np.nan, np.nan, -1, np.nan, np.nan, False, 0,
                          reason=f"the map has fewer than the {needed} frames the query sequence spans")
    start, stop, padded = span
    distances = pairwise(query, map_vectors(start, stop), metric).astype(np.float64)  # type: ignore[arg-type]
    m = stop - start
    best: tuple[float, int, np.ndarray] | None = None
    for slope in slopes.tolist():
        steps = np.floor(np.arange(n) * slope + 0.5).astype(np.int64)
        if speed < 0:
            steps = -steps
        reach = int(np.abs(steps).max())
        for offset in range(m - reach):
            columns = offset + steps if speed > 0 else m - 1 - offset + steps
            cost = float(distances[np.arange(n), columns].sum())
            if best is None or cost < best[0]:
                best = (cost, offset, columns)
    if best is None:
        return FrameMatch(none, np.nan, np.nan, -1, np.nan, np.nan, False, padded,
                          reason=f"the map has fewer than the {needed} frames the query sequence spans")
    cost, offset, columns = best
    per_frame = distances[np.arange(n), columns]
    mean = float(per_frame[informative].mean()) if informative.any() else np.nan
    return FrameMatch(start + columns, cost, mean, offset, cost, np.nan, False, padded, n_distances=distances.size)
