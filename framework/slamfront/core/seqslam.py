"""SeqSLAM (Milford & Wyeth 2012) as OpenSeqSLAM (Suenderhauf et al. 2013) computes it.

The steps, each a function on arrays:

1. :func:`patch_normalise`: every ``side`` x ``side`` patch of the thumbnail becomes
   ``127 + round((p - mean) / std)`` (sample std, MATLAB rounding, uint8 saturation;
   a flat patch becomes 0, as MATLAB's ``uint8(NaN)``).
2. :func:`difference_columns`: the difference matrix ``D[r, q]``, mean absolute
   difference between reference ``r`` and query ``q`` (rows: references).
3. :func:`enhance_contrast`: local contrast enhancement along the reference axis,
   ``(D[r, q] - mean(D[w(r), q])) / std(D[w(r), q])`` over the window
   ``w(r) = r - R/2 .. r + R/2`` (clipped at the ends, sample std). Each query column is
   enhanced on its own, so columns can be computed in any chunking, or one at a time.
4. :func:`sequence_scores`: for a query ``N``, the best straight trajectory through the
   enhanced columns ``N - ds/2 .. N + ds/2`` starting at every reference row, over the
   velocities ``vmin .. vmax`` (:func:`trajectory_offsets`); a trajectory leaving the
   reference costs infinity.
4b. :func:`path_scores_block` (``search: paths``, not OpenSeqSLAM): the best path of
   straight segments at any speed in a wide range, forwards or backwards, through every
   reference row at the query's own column, by dynamic programming.
5. :func:`best_match`: the best start row, and the uniqueness ratio
   ``best / second best outside a window of Rwindow rows`` (lower is surer). The match is
   the start row + ``ds/2``, as OpenSeqSLAM reports it.

OpenSeqSLAM shifts the enhanced matrix so its global minimum is 0 before step 4; the
shift cannot be known before the last query, so online use replaces it by the lowest
value an enhanced entry can take (:func:`enhanced_lower_bound`). The best match does not
depend on the shift; the ratio does, slightly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from slamfront.core.distances import pairwise
from slamfront.core.errors import CoreError
from slamfront.core.kernels import compiled, run_chunks, threads_for


def matlab_round(values: np.ndarray) -> np.ndarray:
    """Round half away from zero, as MATLAB's ``round`` (NumPy rounds half to even)."""
    return np.sign(values) * np.floor(np.abs(values) + 0.5)


def patch_normalise(image: np.ndarray, side: int = 8) -> np.ndarray:
    """OpenSeqSLAM's patch normalisation of a uint8 grey image (H, W) -> uint8 (H, W).

    Only whole patches are normalised; a border narrower than ``side`` is left as it
    is, as in ``patchNormalize.m``.
    """
    if image.ndim != 2:
        raise CoreError(f"patch normalisation needs a grey image, got shape {image.shape}")
    out = image.copy()
    rows, cols = (image.shape[0] // side) * side, (image.shape[1] // side) * side
    if rows == 0 or cols == 0:
        raise CoreError(f"image {image.shape[1]}x{image.shape[0]} is smaller than one {side}x{side} patch")
    blocks = image[:rows, :cols].astype(np.float64).reshape(rows // side, side, cols // side, side)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), ddof=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        normalised = 127.0 + matlab_round((blocks - mean) / std)
    normalised = np.where(std > 0, np.clip(normalised, 0, 255), 0.0)  # uint8(NaN) is 0
    out[:rows, :cols] = normalised.reshape(rows, cols).astype(np.uint8)
    return out


def difference_columns(references: np.ndarray, queries: np.ndarray, threads: int | None = None) -> np.ndarray:
    """(R, Q) float32 mean absolute differences between reference and query vectors.

    :param references: (R, P) descriptors (e.g. patch-normalised thumbnails).
    :param queries: (Q, P).
    :param threads: threads of the distance engine (None: by the amount of work).

    The sums come from the framework's L1 engine (:func:`slamfront.core.distances.pairwise`):
    exact integers for uint8 thumbnails, NumPy's float32 summation order otherwise. Each
    entry is computed the same whatever the chunking, so batch and online use give
    identical bits. No temporary larger than the output is made.
    """
    references = np.asarray(references)
    queries = np.atleast_2d(np.asarray(queries))
    if references.shape[1] != queries.shape[1]:
        raise CoreError(
            f"reference and query descriptors differ in length: {references.shape[1]} vs {queries.shape[1]}"
        )
    if not (references.dtype == np.uint8 and queries.dtype == np.uint8):
        references = references.astype(np.float32, copy=False)
        queries = queries.astype(np.float32, copy=False)
    out = pairwise(references, queries, "l1", threads=threads)
    out /= np.float32(references.shape[1])
    return out


def enhance_contrast(differences: np.ndarray, window: int = 10) -> np.ndarray:
    """(R, Q) float32 locally contrast-enhanced differences (OpenSeqSLAM's ``R`` = window).

    Entries whose window has no spread (std 0) become 0.
    """
    d = np.asarray(differences, dtype=np.float64)
    n = len(d)
    if n < 2:
        raise CoreError("contrast enhancement needs at least 2 references")
    half = window // 2
    rows = np.arange(n)
    lo = np.maximum(rows - half, 0)
    hi = np.minimum(rows + half, n - 1) + 1
    count = (hi - lo)[:, None].astype(np.float64)
    zero = np.zeros((1, d.shape[1]))
    csum = np.concatenate([zero, np.cumsum(d, axis=0)])
    csq = np.concatenate([zero, np.cumsum(d * d, axis=0)])
    total = csum[hi] - csum[lo]
    squares = csq[hi] - csq[lo]
    mean = total / count
    variance = np.maximum(squares - count * mean * mean, 0.0) / np.maximum(count - 1, 1)
    std = np.sqrt(variance)
    with np.errstate(divide="ignore", invalid="ignore"):
        enhanced = np.where(std > 1e-12, (d - mean) / std, 0.0)
    return enhanced.astype(np.float32)


def enhanced_lower_bound(window: int = 10) -> float:
    """The lowest value :func:`enhance_contrast` can give: ``-(n - 1) / sqrt(n)`` for a
    window of ``n = window + 1`` samples (a z-score with sample std)."""
    n = window + 1
    return -(n - 1) / np.sqrt(n)


def trajectory_offsets(ds: int, vmin: float, vmax: float) -> np.ndarray:
    """(V, ds + 1) reference-row offsets of the straight trajectories SeqSLAM tries.

    As ``findSingleMatch``: moves ``vmin*ds, vmin*ds + 1, ..., <= vmax*ds`` give velocities
    ``v = move / ds`` and offsets ``floor(k * v)`` for ``k = 0 .. ds``.
    """
    if ds < 2 or ds % 2:
        raise CoreError(f"ds must be an even number >= 2, got {ds}")
    if not 0 < vmin <= vmax:
        raise CoreError(f"need 0 < vmin <= vmax, got {vmin}, {vmax}")
    moves = np.arange(vmin * ds, vmax * ds + 1e-9, 1.0)
    velocities = moves / ds
    steps = np.arange(ds + 1)
    return np.floor(steps[None, :] * velocities[:, None] + 1e-9).astype(np.int64)


def sequence_scores(columns: np.ndarray, offsets: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Best trajectory cost for every start row.

    :param columns: (R, ds + 1) enhanced (and shifted) differences of the query window.
    :param offsets: (V, ds + 1) from :func:`trajectory_offsets`.
    :param rows: optional sorted start rows to score (others get inf); all when None.
    :returns: (R,) cost of the best trajectory starting at each row (inf: leaves the map).
    """
    if offsets.shape[1] != columns.shape[1]:
        raise CoreError(f"offsets span {offsets.shape[1]} columns but the window has {columns.shape[1]}")
    return sequence_scores_block(columns, offsets, None if rows is None else [rows])[0]


def sequence_scores_block(
    columns: np.ndarray,
    offsets: np.ndarray,
    rows: Sequence[np.ndarray | None] | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """:func:`sequence_scores` of consecutive queries at once (compiled, multi-threaded).

    :param columns: (R, Q + ds) shifted enhanced differences; query ``n``'s window is
        columns ``n .. n + ds``.
    :param offsets: (V, ds + 1) from :func:`trajectory_offsets`.
    :param rows: per query, sorted start rows to score (others inf) or None for all;
        None: all rows of every query.
    :param threads: None: by the amount of work.
    :returns: (Q, R) float64 best trajectory cost per query and start row.

    A query scored on every row adds each trajectory's ``ds + 1`` entries one after the
    other; one with few rows (fewer than R / 8) gathers each trajectory and sums it in
    NumPy's pairwise order; more rows are swept in full and the rest set to inf. These
    are the sums of the former NumPy implementation, bit for bit.
    """
    n_ref, n_columns = columns.shape
    width = offsets.shape[1]
    n_queries = n_columns - width + 1
    if n_queries < 1:
        raise CoreError(f"offsets span {width} columns but the block has {n_columns}")
    if rows is not None and len(rows) != n_queries:
        raise CoreError(f"{len(rows)} row sets for {n_queries} queries")
    reach = int(offsets.max())
    # one contiguous (padded) vector per query column: the sweep's inner loop runs along it
    padded = np.full((n_columns, n_ref + reach + 1), np.inf, dtype=np.float64)
    padded[:, :n_ref] = np.asarray(columns, dtype=np.float64).T
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    out = np.empty((n_queries, n_ref), dtype=np.float64)
    wanted = [None] * n_queries if rows is None else [None if r is None else np.asarray(r, np.int64) for r in rows]
    swept = np.array([n for n, r in enumerate(wanted) if r is None or len(r) * 8 > n_ref], dtype=np.int64)
    gathered = np.array([n for n, r in enumerate(wanted) if r is not None and len(r) * 8 <= n_ref], dtype=np.int64)
    kernels = compiled()
    if threads is None:
        threads = threads_for(float(len(swept)) * n_ref * offsets.size)
    if len(swept):
        run_chunks(lambda lo, hi: kernels.sweep(padded, offsets, swept, out, lo, hi), len(swept), threads)
        for n in swept:
            if wanted[n] is not None:  # a sweep is cheaper than gathering many rows: keep the rows asked for
                keep = np.full(n_ref, np.inf)
                keep[wanted[n]] = out[n, wanted[n]]
                out[n] = keep
    if len(gathered):
        lists = [wanted[n] for n in gathered]
        starts = np.concatenate([[0], np.cumsum([len(r) for r in lists])]).astype(np.int64)
        flat = np.concatenate(lists).astype(np.int64)
        kernels.gather(padded, offsets, gathered, flat, starts, out, 0, len(gathered))
    return out


@dataclass(frozen=True)
class SequenceMatch:
    """The answer for one query: best start row, reported reference row, uniqueness ratio."""

    start: int
    reference: int
    ratio: float


def best_match(scores: np.ndarray, ds: int, rwindow: int = 10) -> SequenceMatch | None:
    """The lowest-cost start row and its ratio to the best one outside ``rwindow``.

    None when no trajectory stays inside the map or nothing lies outside the window.
    """
    if len(scores) == 0 or not np.isfinite(scores).any():
        return None
    start = int(np.argmin(scores))
    lo, hi = max(0, start - rwindow // 2), min(len(scores), start + rwindow // 2 + 1)
    outside = np.concatenate([scores[:lo], scores[hi:]])
    if len(outside) == 0:
        return None
    second = float(outside.min())
    best = float(scores[start])
    ratio = best / second if second > 0 else (0.0 if best == 0 and second == 0 else 1.0)
    return SequenceMatch(start=start, reference=start + ds // 2, ratio=float(ratio))


def path_segments(ds: int, segment: int) -> np.ndarray:
    """(S + 1,) column distances from the middle of a ``ds + 1``-column window where the
    segments of a path end: ``0, segment, 2 segment, ..., ds / 2`` (the last may be shorter)."""
    if ds < 2 or ds % 2:
        raise CoreError(f"ds must be an even number >= 2, got {ds}")
    half = ds // 2
    return np.unique(np.append(np.arange(0, half, max(segment, 1)), half)).astype(np.int64)


def path_offsets(bounds: np.ndarray, low: float, high: float) -> np.ndarray:
    """(S, M, L + 1) row offsets of the segment lines a path may take: segment ``s`` of
    length ``l`` moves ``m`` rows, ``m`` from ``ceil(low * l)`` to ``floor(high * l)`` (speeds
    ``low..high``, :func:`slamfront.core.sequences.cone_speeds` at the segment's resolution),
    ``offsets[s, v, j] = floor(j * m / l)``; shorter segments repeat their last move to fill M."""
    from slamfront.core.sequences import cone_speeds

    lengths = np.diff(bounds)
    moves = [np.unique(np.round(cone_speeds(low, high, int(length), False) * length).astype(np.int64))
             for length in lengths]
    width = max(len(m) for m in moves)
    out = np.zeros((len(lengths), width, int(lengths.max()) + 1), dtype=np.int64)
    for s, (length, m) in enumerate(zip(lengths, moves)):
        m = np.concatenate([m, np.full(width - len(m), m[-1])])
        steps = np.arange(int(length) + 1)
        out[s, :, : length + 1] = np.floor(steps[None, :] * m[:, None] / length + 1e-9).astype(np.int64)
    return out


def path_scores_block(
    columns: np.ndarray,
    ds: int,
    segment: int,
    low: float,
    high: float,
    reverse: bool,
    threads: int | None = None,
) -> np.ndarray:
    """Speed-free sequence search: for each query, the best *path* through every reference
    row at its middle column, over its ``ds + 1`` columns.

    A path is made of straight segments of ``segment`` columns, each at any speed
    ``low..high`` (rows per column), joined end to end, in one direction (with
    ``reverse``, forward and backward paths both; a path does not turn round): a query run
    at a changing pace, or backwards, is followed, and the best path is found by dynamic
    programming over the segment ends (the cost-to-go from the middle to either end,
    Sakoe & Chiba 1978's dynamic time warping with a slope constraint, as in Hansen &
    Browning 2014's HMM sequence search) instead of by trying every line. Work per query:
    ``R x moves x ds`` additions per direction.

    :param columns: (R, Q + ds) shifted enhanced differences; query ``n``'s window is
        columns ``n .. n + ds``.
    :returns: (Q, R) float64 best path cost per query and middle row (inf: no path stays
        inside the reference).
    """
    n_ref, n_columns = columns.shape
    n_queries = n_columns - ds
    if n_queries < 1:
        raise CoreError(f"a window spans {ds + 1} columns but the block has {n_columns}")
    bounds = path_segments(ds, segment)
    offsets = path_offsets(bounds, low, high)
    directions = np.asarray([1, -1] if reverse else [1], dtype=np.int64)
    data = np.ascontiguousarray(np.asarray(columns, dtype=np.float64).T)
    out = np.empty((n_queries, n_ref), dtype=np.float64)
    queries = np.arange(n_queries, dtype=np.int64)
    if threads is None:
        threads = threads_for(float(n_queries) * n_ref * offsets.shape[1] * ds * len(directions))
    kernels = compiled()
    run_chunks(lambda lo, hi: kernels.path_sweep(data, queries, ds // 2, bounds, offsets, directions, out, lo, hi),
               n_queries, threads)
    return out


def path_scores_reference(window: np.ndarray, segment: int, low: float, high: float, reverse: bool) -> np.ndarray:
    """:func:`path_scores_block` for one window (R, ds + 1), the same dynamic programme written
    row by row in NumPy (the tests' oracle: slow), adding in the kernel's order so the two agree
    to the bit."""
    n_ref, width = window.shape
    ds = width - 1
    bounds = path_segments(ds, segment)
    offsets = path_offsets(bounds, low, high)
    half = ds // 2
    best = np.full(n_ref, np.inf)
    for direction in ([1, -1] if reverse else [1]):
        total = window[:, half].astype(np.float64).copy()
        for side in (1, -1):
            sign = direction * side
            togo = np.zeros(n_ref)
            for s in range(len(bounds) - 2, -1, -1):
                b, length = bounds[s], bounds[s + 1] - bounds[s]
                new = np.full(n_ref, np.inf)
                for v in range(offsets.shape[1]):
                    for r in range(n_ref):
                        rows = r + sign * offsets[s, v, 1 : length + 1]
                        end = r + sign * offsets[s, v, length]
                        if not 0 <= end < n_ref or rows.min() < 0 or rows.max() >= n_ref:
                            continue
                        cols = half + side * (b + np.arange(1, length + 1))
                        line = 0.0
                        for value in window[rows, cols]:  # one after the other, as the kernel adds them
                            line += float(value)
                        new[r] = min(new[r], line + togo[end])
                togo = new
            total += togo
        best = np.minimum(best, total)
    return best
