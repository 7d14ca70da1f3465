"""Loop-closure ground truth and precision-recall, on plain arrays.

Conventions (docs/design.md, "Contracts"): recall counts the queries that have a true match;
precision counts accepted reports. A query answered with "no answer" is never accepted.
Frames are identified by their stream index everywhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from slamfront.core.errors import CoreError


@dataclass(frozen=True)
class LoopGroundTruth:
    """For each frame evaluated as a query, the set of frames that are a correct match.

    Stored in compressed-row form: the correct matches of ``queries[i]`` are
    ``matches[indptr[i]:indptr[i + 1]]`` (sorted). An empty row means the query has no
    true match (the place was never seen before): any report for it is a false positive.

    :ivar queries: (Q,) int64 frame indices, sorted, unique.
    :ivar indptr: (Q + 1,) int64 row offsets into ``matches``.
    :ivar matches: (M,) int64 frame indices.
    """

    queries: np.ndarray
    indptr: np.ndarray
    matches: np.ndarray

    def __post_init__(self) -> None:
        if self.indptr.shape != (len(self.queries) + 1,):
            raise CoreError("indptr must have one entry more than queries")
        if len(self.queries) > 1 and np.any(np.diff(self.queries) <= 0):
            raise CoreError("query frame indices must be sorted and unique")

    @classmethod
    def band(
        cls,
        queries: np.ndarray,
        centres: np.ndarray,
        tolerance: int,
        valid: tuple[int, int] | None = None,
    ) -> LoopGroundTruth:
        """Paired traversals: query ``queries[i]`` matches ``centres[i] +- tolerance``.

        :param queries: (Q,) frame indices of the queries.
        :param centres: (Q,) frame index of each query's true match, -1 when it has none.
        :param tolerance: zeta, in frames (3 in Rodrigues 2019).
        :param valid: inclusive (first, last) frame indices a match may take (the
            reference traversal); the band is clipped to it.
        """
        queries = np.asarray(queries, dtype=np.int64)
        centres = np.asarray(centres, dtype=np.int64)
        if queries.shape != centres.shape:
            raise CoreError(f"{len(queries)} queries but {len(centres)} ground-truth entries")
        if tolerance < 0:
            raise CoreError("tolerance must be >= 0")
        order = np.argsort(queries, kind="stable")
        queries, centres = queries[order], centres[order]
        lo_valid, hi_valid = valid if valid is not None else (0, np.iinfo(np.int64).max)
        rows = []
        for centre in centres:
            if centre < 0:
                rows.append(np.empty(0, dtype=np.int64))
                continue
            lo, hi = max(centre - tolerance, lo_valid), min(centre + tolerance, hi_valid)
            rows.append(np.arange(lo, hi + 1, dtype=np.int64))
        return cls.from_rows(queries, rows)

    @classmethod
    def from_places(
        cls,
        queries: np.ndarray,
        query_places: Sequence[np.ndarray],
        frames: np.ndarray,
        frame_places: np.ndarray,
        tolerance: float,
    ) -> LoopGroundTruth:
        """Ground truth from where along a route every frame is.

        Each candidate frame has a place coordinate (its position along the reference
        route: the frame number in the original traversal, or metres); a query is at one
        or more places. A report is correct when the matched frame's place is within
        ``tolerance`` of one of the query's places. Unlike :meth:`band`, this stays right
        when the candidates were reordered or partly replaced (Rodrigues 2019 §4.4,
        experiments 2 and 3).

        :param queries: (Q,) frame indices of the queries.
        :param query_places: Q arrays of the places each query shows (empty: a place
            never seen in the candidates, so any report is a false positive).
        :param frames: (R,) frame indices that may be reported as matches.
        :param frame_places: (R,) float place of each candidate; NaN for frames of no
            place on the route (replaced by another dataset's frames).
        :param tolerance: zeta, in place units.
        """
        queries = np.asarray(queries, dtype=np.int64)
        frames = np.asarray(frames, dtype=np.int64)
        frame_places = np.asarray(frame_places, dtype=np.float64)
        if len(query_places) != len(queries):
            raise CoreError(f"{len(queries)} queries but {len(query_places)} ground-truth entries")
        if frames.shape != frame_places.shape:
            raise CoreError(f"{len(frames)} candidate frames but {len(frame_places)} places")
        if tolerance < 0:
            raise CoreError("tolerance must be >= 0")
        known = np.isfinite(frame_places)
        order = np.argsort(frame_places[known], kind="stable")
        sorted_places, sorted_frames = frame_places[known][order], frames[known][order]
        rows = []
        for places in query_places:
            places = np.asarray(places, dtype=np.float64).ravel()
            lo = np.searchsorted(sorted_places, places - tolerance, side="left")
            hi = np.searchsorted(sorted_places, places + tolerance, side="right")
            hits = [sorted_frames[a:b] for a, b in zip(lo, hi)]
            rows.append(np.unique(np.concatenate(hits)) if hits else np.empty(0, dtype=np.int64))
        order_q = np.argsort(queries, kind="stable")
        return cls.from_rows(queries[order_q], [rows[i] for i in order_q])

    @classmethod
    def from_rows(cls, queries: np.ndarray, rows: Sequence[np.ndarray]) -> LoopGroundTruth:
        """Build from one array of correct matches per query."""
        queries = np.asarray(queries, dtype=np.int64)
        if len(rows) != len(queries):
            raise CoreError(f"{len(queries)} queries but {len(rows)} rows of matches")
        lengths = np.array([len(r) for r in rows], dtype=np.int64)
        indptr = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        matches = (
            np.concatenate([np.sort(np.asarray(r, dtype=np.int64)) for r in rows])
            if rows
            else np.empty(0, dtype=np.int64)
        )
        return cls(queries=queries, indptr=indptr, matches=matches.astype(np.int64))

    def __len__(self) -> int:
        return len(self.queries)

    def has_true_match(self) -> np.ndarray:
        """(Q,) bool: which queries have at least one correct match."""
        return np.diff(self.indptr) > 0

    def rows_of(self, frames: np.ndarray) -> np.ndarray:
        """(N,) row of each frame in ``queries``; -1 for frames that are not queries."""
        frames = np.asarray(frames, dtype=np.int64)
        if len(self.queries) == 0:
            return np.full(len(frames), -1, dtype=np.int64)
        pos = np.clip(np.searchsorted(self.queries, frames), 0, len(self.queries) - 1)
        return np.where(self.queries[pos] == frames, pos, -1)

    def is_correct(self, frames: np.ndarray, matches: np.ndarray) -> np.ndarray:
        """(N,) bool: is ``matches[k]`` a correct match for query ``frames[k]``?"""
        rows = self.rows_of(frames)
        matches = np.asarray(matches, dtype=np.int64)
        out = np.zeros(len(rows), dtype=bool)
        valid = (rows >= 0) & (matches >= 0)
        if not valid.any() or len(self.matches) == 0:
            return out
        # one search over all queries at once: (row, match) pairs as row * span + match,
        # which keeps the CSR order (rows ascending, each row's matches sorted)
        span = int(max(self.matches.max(), matches[valid].max())) + 1
        stored = np.repeat(np.arange(len(self.indptr) - 1, dtype=np.int64), np.diff(self.indptr)) * span + self.matches
        asked = rows[valid].astype(np.int64) * span + matches[valid]
        j = np.minimum(np.searchsorted(stored, asked), len(stored) - 1)
        out[valid] = stored[j] == asked
        return out

    def subset(self, keep: np.ndarray) -> LoopGroundTruth:
        """The ground truth of the queries where ``keep`` (Q,) bool is True."""
        keep = np.asarray(keep, dtype=bool)
        rows = [self.matches[self.indptr[k] : self.indptr[k + 1]] for k in np.flatnonzero(keep)]
        return LoopGroundTruth.from_rows(self.queries[keep], rows)

    def is_correct_place(
        self, frames: np.ndarray, matches: np.ndarray, places: Sequence[np.ndarray | None]
    ) -> np.ndarray:
        """(N,) bool: is any frame of the matched place ``places[k]`` a correct match for ``frames[k]``?

        Place scoring: a detector that merges similar frames into one place answers with
        the place, and the place is the right one when any frame it stands for is.
        ``places[k]`` None (a detector without places) scores ``matches[k]`` alone;
        ``matches[k]`` -1 (no answer) is never correct.
        """
        matches = np.asarray(matches, dtype=np.int64)
        out = self.is_correct(frames, matches)
        rows = self.rows_of(frames)
        for k, (row, place) in enumerate(zip(rows, places)):
            if out[k] or row < 0 or matches[k] < 0 or place is None or len(place) == 0:
                continue
            correct = self.matches[self.indptr[row] : self.indptr[row + 1]]
            out[k] = bool(np.isin(np.asarray(place, dtype=np.int64), correct).any())
        return out

    def centre_of(self, frames: np.ndarray) -> np.ndarray:
        """(N,) the middle correct match of each query (for plots); -1 when none."""
        rows = self.rows_of(frames)
        out = np.full(len(rows), -1, dtype=np.int64)
        for k, row in enumerate(rows):
            if row >= 0 and self.indptr[row + 1] > self.indptr[row]:
                out[k] = self.matches[(self.indptr[row] + self.indptr[row + 1] - 1) // 2]
        return out


@dataclass(frozen=True)
class PrecisionRecall:
    """A precision-recall curve from sweeping a confidence threshold.

    :ivar thresholds: (T,) confidence thresholds, decreasing; a report is accepted
        when its confidence is >= the threshold.
    :ivar precision: (T,) precision at each threshold (1 where nothing is accepted).
    :ivar recall: (T,) recall at each threshold.
    """

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    n_positive: int

    @property
    def recall_at_100p(self) -> float:
        """Largest recall reached with no false positive (0 when the first report is wrong)."""
        perfect = self.precision >= 1.0
        return float(self.recall[perfect].max()) if np.any(perfect) else 0.0

    @property
    def auc(self) -> float:
        """Area under the curve as average precision: sum of (R_k - R_{k-1}) * P_k."""
        if len(self.recall) == 0:
            return 0.0
        recall = np.concatenate([[0.0], self.recall])
        return float(np.sum(np.diff(recall) * self.precision))

    def threshold_at_100p(self) -> float:
        """The lowest threshold that still gives 100 % precision (inf when none does)."""
        perfect = np.flatnonzero(self.precision >= 1.0)
        if len(perfect) == 0:
            return float("inf")
        best = perfect[np.argmax(self.recall[perfect])]
        return float(self.thresholds[best])


def precision_recall(
    confidence: np.ndarray, answered: np.ndarray, correct: np.ndarray, n_positive: int
) -> PrecisionRecall:
    """Sweep the confidence threshold over the answered reports.

    :param confidence: (N,) confidence of each report, higher is surer.
    :param answered: (N,) bool, False for "no answer" (never accepted).
    :param correct: (N,) bool, the report's match is a correct one.
    :param n_positive: how many queries have a true match (the recall denominator).
    :returns: the curve with one point per distinct confidence (ties enter together).
    """
    confidence = np.asarray(confidence, dtype=np.float64)
    answered = np.asarray(answered, dtype=bool) & np.isfinite(confidence)
    correct = np.asarray(correct, dtype=bool)
    conf, hit = confidence[answered], correct[answered]
    order = np.argsort(-conf, kind="stable")
    conf, hit = conf[order], hit[order]
    tp = np.cumsum(hit)
    fp = np.cumsum(~hit)
    # cut only at the end of each group of equal confidences: a threshold accepts all ties
    last_of_group = np.r_[conf[1:] != conf[:-1], True] if len(conf) else np.zeros(0, bool)
    tp, fp, thresholds = tp[last_of_group], fp[last_of_group], conf[last_of_group]
    accepted = tp + fp
    precision = np.where(accepted > 0, tp / np.maximum(accepted, 1), 1.0)
    recall = tp / n_positive if n_positive > 0 else np.zeros_like(tp, dtype=np.float64)
    return PrecisionRecall(
        thresholds=thresholds,
        precision=precision.astype(np.float64),
        recall=np.asarray(recall, dtype=np.float64),
        n_positive=int(n_positive),
    )


def recall_at_k(
    frames: np.ndarray, candidates: Sequence[np.ndarray], truth: LoopGroundTruth, ks: Sequence[int]
) -> dict[int, float]:
    """Fraction of queries with a true match whose top-K candidates contain a correct one.

    :param frames: (N,) query frame indices.
    :param candidates: N arrays of candidate frame indices, best first.
    :param ks: the K values to report.
    """
    rows = truth.rows_of(frames)
    positives = truth.has_true_match()
    n_positive = int(positives.sum())
    first_hit = np.full(len(frames), np.iinfo(np.int64).max)
    asked = [
        k for k, cands in enumerate(candidates)
        if rows[k] >= 0 and positives[rows[k]] and cands is not None and len(cands) > 0
    ]
    if asked:  # every candidate of every query checked in one call
        lengths = np.array([len(candidates[k]) for k in asked])
        starts = np.r_[0, np.cumsum(lengths)[:-1]]
        ok = truth.is_correct(
            np.repeat(np.asarray(frames)[asked], lengths), np.concatenate([np.asarray(candidates[k]) for k in asked])
        )
        position = np.arange(len(ok)) - np.repeat(starts, lengths)
        first_hit[asked] = np.minimum.reduceat(np.where(ok, position, np.iinfo(np.int64).max), starts)
    return {k: float(np.sum(first_hit < k) / n_positive) if n_positive else 0.0 for k in ks}


def revisits_from_positions(
    positions: np.ndarray, radius_m: float, leave_m: float | None = None
) -> LoopGroundTruth:
    """Stream loop ground truth from where the camera was: a frame revisits every earlier
    frame it is within ``radius_m`` of, provided the camera *left* that place in between
    (went farther than ``leave_m`` from it) - a return, not standing still.

    This is the synthetic world's stream truth (a revisit radius, counted only after
    leaving) defined on positions alone, so any source with ground-truth poses has it.

    :param positions: (N, 3) camera positions of frames 0..N-1, in metres.
    :param radius_m: how close a return must come to count as a revisit.
    :param leave_m: how far the camera must go between the two visits (default
        ``2 * radius_m``).
    :returns: every frame as a query; row i lists the frames i revisits (maybe none).
    """
    from scipy.spatial import cKDTree

    points = np.asarray(positions, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise CoreError(f"positions must be (N, 3), got {points.shape}")
    if radius_m <= 0:
        raise CoreError(f"the revisit radius must be positive, got {radius_m}")
    leave = 2.0 * radius_m if leave_m is None else float(leave_m)
    n = len(points)
    # left[j]: the first frame after j farther than `leave` from frame j (n: it never left)
    left = np.full(n, n, dtype=np.int64)
    for j in range(n):
        start, width = j + 1, 64
        while start < n:
            far = np.flatnonzero(np.linalg.norm(points[start : start + width] - points[j], axis=1) > leave)
            if far.size:
                left[j] = start + far[0]
                break
            start += width
            width *= 2
    rows: list[np.ndarray] = []
    tree = cKDTree(points) if n else None
    for i in range(n):
        near = np.asarray(tree.query_ball_point(points[i], radius_m), dtype=np.int64) if tree is not None else []
        near = near[near < i] if len(near) else np.empty(0, np.int64)
        rows.append(near[left[near] < i])
    return LoopGroundTruth.from_rows(np.arange(n, dtype=np.int64), rows)
