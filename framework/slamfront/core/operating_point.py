"""The acceptance threshold of a loop detector, calibrated from wrong answers it has seen.

A SLAM back end consumes the closures a detector *accepts*; one false closure can bend a
map. The threshold is therefore set at a chosen false-accept rate of the detector's own
confidence on answers known to be wrong without any query ground truth:

- paired traversals: the reference traversal searched against itself outside a temporal
  exclusion window (a traversal does not revisit itself, so every answer there is wrong);
- a stream: the answers to its first frames, before any revisit is possible.

The threshold is the ``1 - rate`` quantile of those wrong confidences (the largest of them
when there are fewer than ``1 / rate``), times ``margin``: every answer of the detector
at or above it is accepted. Pure array functions; the detectors' shared bookkeeping is
:mod:`slamfront.acceptance`.
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

from slamfront.core.errors import CoreError


def threshold_at_false_accept_rate(wrong: np.ndarray, rate: float, margin: float = 1.0) -> float:
    """The confidence at or above which at most ``rate`` of the ``wrong`` answers lie.

    ``wrong``: confidences of answers known to be wrong (NaN ignored). Returns the
    smallest threshold ``t`` with ``mean(wrong >= t) <= rate``, taken just above a wrong
    confidence (``nextafter``), times ``margin`` and capped at 1 (1: accept nothing
    short of certainty; with no wrong answer at all, the threshold is 1 too).
    """
    if not 0.0 <= rate < 1.0:
        raise CoreError(f"false-accept rate must be in [0, 1), got {rate}")
    values = np.sort(np.asarray(wrong, dtype=np.float64).ravel())
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return 1.0
    allowed = int(np.floor(rate * len(values)))  # wrong answers that may be accepted
    above = float(values[len(values) - 1 - allowed])  # the largest wrong confidence that must be rejected
    return float(min(1.0, np.nextafter(above, np.inf) * margin))


def outlier_discounted_threshold(threshold: float, decisions: np.ndarray | list[float], rate: float) -> float:
    """``threshold`` (from :func:`threshold_at_false_accept_rate`), lowered when the largest of
    the wrong ``decisions`` (one confidence per decision, for detectors that judge a whole
    sequence of answers at once) is an outlier of the others.

    With a few dozen decisions and a small ``rate`` the threshold is just above the largest
    wrong decision, so one decision unlike the rest (a stretch of the reference that looks like
    another) sets it alone. The decisions are fitted robustly by a normal distribution
    (median, and 1.4826 x the median absolute deviation as its spread; the modified z-score of
    Iglewicz and Hoaglin 1993): when the largest lies above that fit's ``1 - rate`` quantile,
    the threshold is that quantile, but never below the second-largest decision (only one
    decision is discounted) and never above ``threshold``. Fewer than three decisions, or no
    spread, leave ``threshold`` as it is."""
    values = np.sort(np.asarray(decisions, dtype=np.float64).ravel())
    values = values[np.isfinite(values)]
    if len(values) < 3 or not 0.0 < rate < 1.0:
        return float(threshold)
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    fitted = median + NormalDist().inv_cdf(1.0 - rate) * spread
    if spread <= 0 or values[-1] <= fitted:
        return float(threshold)
    return float(min(threshold, max(np.nextafter(values[-2], np.inf), fitted)))


def query_null_threshold(reference: float, null: np.ndarray | list[float], rate: float) -> float:
    """The threshold under the queries' own appearance: the ``rate`` threshold of ``null``
    (the queries' leave-the-answer-out confidences: what the detector answers with the
    answered stretch of the map left out, wrong by construction), but never above
    ``reference`` (the threshold from the reference against itself). A query traversal
    seen under another appearance (dusk, night, another season) answers every place, right
    or wrong, less confidently than the reference answers itself, so the reference's
    threshold is too high for it; its own wrong answers say how far down it may go."""
    return min(float(reference), threshold_at_false_accept_rate(np.asarray(null, dtype=np.float64), rate))


def query_shift_threshold(reference: float, reference_median: float, null: np.ndarray | list[float]) -> float:
    """The threshold under the queries' own appearance, by a shift: ``reference`` (the
    threshold from the reference against itself) moved by ``median(null) - reference_median``
    (``reference_median``: the median of the reference's wrong confidences), never above
    ``reference``. It takes the tail's shape from the reference's many wrong answers and only
    their location from the queries' leave-the-answer-out confidences: a median is sound from
    a few dozen values, where their largest (:func:`query_null_threshold` at a small rate)
    still underestimates the tail, which matters when one value stands for a whole sequence
    of answers."""
    return min(float(reference), float(reference) + float(np.median(np.asarray(null, dtype=np.float64)))
               - float(reference_median))


def exclusion_window(n: int, frames: int) -> int:
    """The temporal exclusion window for a traversal of ``n`` frames: ``frames``, but at most a
    tenth of the traversal (at least 1), so a short reference (a room's 111 frames) keeps
    most of itself as wrong candidates."""
    return max(1, min(frames, n // 10))


def self_split(n: int, frames: int, most: int) -> tuple[int, int]:
    """Paired traversals searched against themselves by a detector that keeps a map growing
    in time: the last third of the ``n`` frames (at most ``most``) are the queries, from
    position ``start``; the map is the frames before ``horizon`` = ``start`` minus the
    exclusion window. Returns ``(start, horizon)``."""
    start = n - min(n // 3, most)
    return start, start - exclusion_window(n, frames)


def exclusion_masked(distances: np.ndarray, rows: np.ndarray, columns: np.ndarray, window: int) -> np.ndarray:
    """``distances`` (rows x columns of one traversal against itself) with every entry
    whose row and column frame positions are at most ``window`` apart set to +inf: what
    a search for a *wrong* match may not return."""
    near = np.abs(np.asarray(rows)[:, None] - np.asarray(columns)[None, :]) <= window
    return np.where(near, np.inf, distances)


def uniqueness_confidence(distances: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Per column of ``distances`` (candidates x queries, +inf: not a candidate): the best
    candidate and the confidence ``1 - d_best / d_second``, ``d_second`` the best distance
    more than ``window`` candidates away from the best (as the nearest-neighbour
    detector's). Returns ``(best, confidence)``."""
    d = np.asarray(distances, dtype=np.float64)
    best = np.argmin(d, axis=0)
    d_best = d[best, np.arange(d.shape[1])]
    far = np.abs(np.arange(d.shape[0])[:, None] - best[None, :]) > window
    second = np.where(far, d, np.inf).min(axis=0)
    second = np.where(np.isfinite(second), second, d_best * 2 + 1e-9)
    confidence = np.clip(1.0 - d_best / np.maximum(second, 1e-12), 0.0, 1.0)
    return best, np.where(np.isfinite(d_best), confidence, np.nan)


def distinctiveness(cost: float, alternatives: np.ndarray | list[float]) -> float:
    """How much better an answer fits than the best alternative elsewhere: ``1 - cost / second``,
    ``second`` the lowest of the ``alternatives``' costs (answers far enough from this one to be
    another place; NaN ignored), clipped to [0, 1]. SeqSLAM's uniqueness ratio (Milford and
    Wyeth 2012), the form of :func:`uniqueness_confidence` for one answer.

    A change of appearance (night, another season) raises every cost about alike, so the ratio
    drops far less than a confidence taken from the cost alone. 0 when there is no alternative
    (nothing to tell the answer apart from), when the best alternative costs nothing, or when
    ``cost`` is NaN; 1 when every alternative costs +inf."""
    values = np.asarray(alternatives, dtype=np.float64).ravel()
    values = values[~np.isnan(values)]
    if not len(values) or np.isnan(cost):
        return 0.0
    second = float(values.min())
    if second <= 0:
        return 0.0
    return float(np.clip(1.0 - float(cost) / second, 0.0, 1.0))


def self_queries(n: int, window: int, most: int) -> np.ndarray:
    """Positions of a traversal of ``n`` frames to search against the rest of itself, at
    most ``most`` of them, evenly spread (every frame when it has no more than ``most``);
    empty when no frame has a frame more than ``window`` away."""
    if n <= window + 1:
        return np.empty(0, dtype=np.int64)
    if n <= most:
        return np.arange(n, dtype=np.int64)
    return np.unique(np.linspace(0, n - 1, most).round().astype(np.int64))


def moving(distances: np.ndarray, rows: np.ndarray, columns: np.ndarray, still: float = 0.1) -> np.ndarray:
    """(q,) bool: self-queries (``columns``, frame positions; ``distances`` rows x columns of
    the traversal against itself) taken while the vehicle moved: the distance to the frame's
    own next or previous frame is above ``still`` times the median such distance. A frame
    at a stop longer than the exclusion window can pair with the same place, so its answer
    is not known to be wrong and is left out."""
    rows = np.asarray(rows)
    position = {int(r): k for k, r in enumerate(rows.tolist())}
    adjacent = np.full(len(columns), np.inf)
    for k, c in enumerate(np.asarray(columns).tolist()):
        for neighbour in (c - 1, c + 1):
            if neighbour in position:
                adjacent[k] = min(adjacent[k], float(distances[position[neighbour], k]))
    finite = adjacent[np.isfinite(adjacent)]
    if len(finite) == 0:
        return np.ones(len(columns), dtype=bool)
    return adjacent > still * float(np.median(finite))


def travelled(adjacent: np.ndarray) -> np.ndarray:
    """(n,) how far a traversal of ``n`` frames has come at each frame, in typical frames,
    from ``adjacent`` ((n - 1,) the distance between each frame's descriptor and the next
    one's): a step counts as one frame when its frames differ at least as much as the
    median step's do, and as that fraction of a frame when they differ less (a vehicle
    crawling or stopped barely changes its view). An exclusion window measured along it
    (:func:`exclusion_masked` with these positions) keeps frames of one place together
    when the reference moves slowly: a frame counted there is the reference's own pace,
    calibrated from the reference, not a clock tick. NaN or infinite steps count as one."""
    steps = np.asarray(adjacent, dtype=np.float64).ravel()
    finite = steps[np.isfinite(steps)]
    typical = float(np.median(finite)) if len(finite) else 0.0
    if typical <= 0:
        fraction = np.ones(len(steps))
    else:
        fraction = np.where(np.isfinite(steps), np.clip(steps / typical, 0.0, 1.0), 1.0)
    return np.concatenate([[0.0], np.cumsum(fraction)])
