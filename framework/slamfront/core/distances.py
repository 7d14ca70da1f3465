"""Distances between descriptors, vectorised and chunked.

Metrics: ``l1`` (sum of absolute differences), ``l2`` (Euclidean), ``cosine``
(1 - cosine similarity) and ``hamming`` (differing bits of uint8-packed binary
descriptors).
"""

from __future__ import annotations

import functools
from contextlib import AbstractContextManager
from typing import Any, Literal

import numpy as np
from threadpoolctl import ThreadpoolController

from slamfront.core.errors import CoreError
from slamfront.core.kernels import compiled, run_chunks, threads_for

Metric = Literal["l1", "l2", "cosine", "hamming"]
METRICS: tuple[Metric, ...] = ("l1", "l2", "cosine", "hamming")

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


@functools.cache
def _threadpools() -> ThreadpoolController:
    """The process's BLAS/OpenMP pools, inspected once (a limit is then ~10 us, not ~0.5 ms)."""
    return ThreadpoolController()


def single_threaded_blas() -> AbstractContextManager[Any]:
    """BLAS limited to one thread inside the ``with`` block.

    For the many small products of per-frame work (hundreds of features against a few
    thousand words) OpenBLAS's thread hand-off costs more than it saves, and on a busy
    machine its threads spin: a 40x16 by 16x3000 product took 40 ms with the default
    threads and 2.4 ms with one, at load 12 on 2 cores (300x128 by 128x30000: 429 vs
    477 ms, so large products lose little).
    """
    return _threadpools().limit(limits=1, user_api="blas")


def pairwise(
    a: np.ndarray, b: np.ndarray, metric: Metric, chunk: int = 1024, max_elements: int = 1 << 22,
    threads: int | None = None,
) -> np.ndarray:
    """(N, M) float32 distances between the rows of ``a`` (N, D) and ``b`` (M, D).

    The one all-pairs engine: retrieval evaluation, SeqSLAM's difference matrix,
    brute-force place search and the nearest-neighbour detector all come here.

    - L1 of two uint8 or two float32 matrices runs compiled loops
      (:mod:`slamfront.core.kernels`) split over ``threads`` threads (None: by the
      amount of work), with no temporary beyond the output. uint8 sums are exact
      integers; float32 sums repeat NumPy's pairwise order, so the values are the same
      bits ``np.abs(a - b).sum(-1)`` gives.
    - L2 and cosine use one BLAS product (float64).
    - Hamming (and L1 of other dtypes) work in row chunks of ``a``: at most ``chunk``
      rows and at most ``max_elements`` temporary elements (``rows * M * D``); each
      distance is summed over its own row whatever the chunking.
    """
    a = np.atleast_2d(a)
    b = np.atleast_2d(b)
    if a.shape[1] != b.shape[1]:
        raise CoreError(f"descriptor lengths differ: {a.shape[1]} vs {b.shape[1]}")
    if metric not in METRICS:
        raise CoreError(f"unknown metric {metric!r}; one of {', '.join(METRICS)}")
    if metric == "l2":
        a64, b64 = a.astype(np.float64), b.astype(np.float64)
        sq = (a64**2).sum(1)[:, None] + (b64**2).sum(1)[None, :] - 2.0 * a64 @ b64.T
        return np.sqrt(np.maximum(sq, 0.0)).astype(np.float32)
    if metric == "cosine":
        na = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
        nb = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
        return (1.0 - na.astype(np.float64) @ nb.astype(np.float64).T).astype(np.float32)
    if metric == "l1" and a.dtype == b.dtype and a.dtype in (np.uint8, np.float32):
        return _compiled_l1(a, b, threads)
    out = np.empty((len(a), len(b)), dtype=np.float32)
    chunk = max(1, min(chunk, max_elements // max(b.size, 1)))
    words = None
    if metric == "hamming" and a.dtype == b.dtype == np.uint8 and a.shape[1] % 8 == 0 and hasattr(np, "bitwise_count"):
        words = np.ascontiguousarray(b).view(np.uint64)
    for start in range(0, len(a), chunk):
        block = a[start : start + chunk]
        if metric == "l1":
            out[start : start + chunk] = np.abs(block[:, None, :].astype(np.float32) - b[None, :, :]).sum(-1)
        else:
            if a.dtype != np.uint8 or b.dtype != np.uint8:
                raise CoreError("hamming distance needs uint8-packed binary descriptors")
            if words is not None:  # numpy's popcount on 64-bit words: 8 bytes at a time
                packed = np.ascontiguousarray(block).view(np.uint64)
                out[start : start + chunk] = np.bitwise_count(np.bitwise_xor(packed[:, None, :], words[None])).sum(-1)
            else:
                out[start : start + chunk] = _POPCOUNT[np.bitwise_xor(block[:, None, :], b[None, :, :])].sum(-1)
    return out


def rowwise(a: np.ndarray, b: np.ndarray, metric: Metric) -> np.ndarray:
    """(N,) float32 distances between ``a[i]`` and ``b[i]`` (both (N, D)): only the pairs
    asked for, where :func:`pairwise` would compute all N x M. Each distance has the same
    bits as :func:`pairwise` gives for that pair (same per-row reduction)."""
    a = np.atleast_2d(a)
    b = np.atleast_2d(b)
    if a.shape != b.shape:
        raise CoreError(f"rowwise distances need arrays of one shape, got {a.shape} and {b.shape}")
    if metric == "l1":
        return np.abs(a.astype(np.float32) - b).sum(-1).astype(np.float32, copy=False)
    if metric == "hamming":
        if a.dtype != np.uint8 or b.dtype != np.uint8:
            raise CoreError("hamming distance needs uint8-packed binary descriptors")
        return _POPCOUNT[np.bitwise_xor(a, b)].sum(-1).astype(np.float32)
    return np.array([pairwise(x[None, :], y[None, :], metric)[0, 0] for x, y in zip(a, b)], dtype=np.float32)


def _compiled_l1(a: np.ndarray, b: np.ndarray, threads: int | None) -> np.ndarray:
    """L1 of two uint8 or two float32 matrices with the compiled kernels (see :func:`pairwise`)."""
    kernels = compiled()
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    n = len(a)
    if threads is None:
        threads = threads_for(float(a.shape[0]) * b.shape[0] * b.shape[1])
    if a.dtype == np.uint8:
        sums = np.empty((n, len(b)), dtype=np.int32)
        run_chunks(lambda lo, hi: kernels.l1_uint8(a, b, sums, lo, hi), n, threads)
        return sums.astype(np.float32)  # exact: at most 255 * D < 2**24 for D <= 65,793
    out = np.empty((n, len(b)), dtype=np.float32)
    run_chunks(lambda lo, hi: kernels.l1_float32(a, b, out, lo, hi), n, threads)
    return out


def smallest(values: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` smallest entries of each row of ``values`` (..., M), smallest
    first, ties by index: exactly ``np.argsort(values, kind="stable")[..., :k]``, without
    sorting everything (a partition finds the k-th value, then only the entries up to it
    are sorted). NaN is not supported."""
    values = np.asarray(values)
    m = values.shape[-1]
    k = min(k, m)
    if k == 0:
        return np.empty((*values.shape[:-1], 0), dtype=np.int64)
    if 4 * k >= m:
        return np.argsort(values, axis=-1, kind="stable")[..., :k]
    flat = values.reshape(-1, m)
    out = np.empty((len(flat), k), dtype=np.int64)
    kth = np.partition(flat, k - 1, axis=1)[:, k - 1 : k]
    for i, (row, bound) in enumerate(zip(flat, kth)):
        chosen = np.flatnonzero(row <= bound[0])  # ascending index: a stable sort keeps ties in index order
        out[i] = chosen[np.argsort(row[chosen], kind="stable")[:k]]
    return out.reshape(*values.shape[:-1], k)


def to_one(query: np.ndarray, rows: np.ndarray, metric: Metric) -> np.ndarray:
    """(M,) distances from one descriptor ``query`` (D,) to each row of ``rows`` (M, D)."""
    return pairwise(query[None, :], rows, metric)[0]


def k_nearest(queries: np.ndarray, rows: np.ndarray, k: int, metric: Metric) -> np.ndarray:
    """(Q, min(k, M)) int64 indices of the ``k`` nearest rows to each query, nearest first.

    Ties are broken by row index (as a stable sort of all distances), so the answer is
    deterministic. Queries go to :func:`pairwise` in blocks whose distance matrix stays
    near 64 MB whatever Q and M.
    """
    queries = np.atleast_2d(queries)
    k = min(k, len(rows))
    chunk = max(1, (1 << 24) // max(1, len(rows)))
    out = np.empty((len(queries), k), dtype=np.int64)
    bounded = metric == "l1" and queries.dtype == rows.dtype == np.float32 and 0 < k < len(rows)
    for start in range(0, len(queries), chunk):
        if bounded:
            out[start : start + chunk] = _k_nearest_l1_float32(queries[start : start + chunk], rows, k)
        else:
            out[start : start + chunk] = smallest(pairwise(queries[start : start + chunk], rows, metric), k)
    return out


_UNIT_ROUNDOFF = 2.0**-24
"""float32's unit roundoff: a sum of p non-negative float32 terms, in any order, is within
(p - 1) times it (relative to the sum) of the exact sum of those terms."""


def _k_nearest_l1_float32(queries: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """:func:`k_nearest` for float32 L1, the same answer as ranking :func:`pairwise`'s bits.

    :func:`pairwise` sums every distance in NumPy's pairwise order (so that a distance has
    the same bits wherever it is computed), which keeps the compiler from vectorising it.
    Ranking only needs that order near the cut: all distances are computed first by a
    vectorised kernel whose sums may differ from those bits by at most
    ``e = 2 (p - 1) u S`` (``u`` = 2**-24, ``S`` the distance); every row that can be among
    the ``k`` nearest has a bounded distance within ``2 e`` of the k-th bounded one, and only
    those few are recomputed with :func:`pairwise`'s bits and ranked (stable, ties by row
    index), as :func:`smallest` ranks the whole matrix.
    """
    kernels = compiled()
    queries, rows = np.ascontiguousarray(queries), np.ascontiguousarray(rows)
    n, p = len(queries), rows.shape[1]
    bounded = np.empty((n, len(rows)), dtype=np.float32)
    tiny = np.finfo(np.float32).tiny
    kept: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def bound(lo: int, hi: int) -> None:
        # the bounded distances of queries lo..hi-1, then, on the same thread while they are
        # in cache, the rows each query keeps: those within the margin of its k-th bounded one
        kernels.l1_float32_bound(queries, rows, bounded, lo, hi)
        kth = np.partition(bounded[lo:hi], k - 1, axis=1)[:, k - 1].astype(np.float64)
        # 2 e on each side, e taken at the largest sum a kept row can have, with 10 % to spare
        margin = 4.4 * p * _UNIT_ROUNDOFF * kth + tiny
        query, row = np.nonzero(bounded[lo:hi] <= (kth + margin)[:, None])
        kept[lo] = (query + lo, row)

    run_chunks(bound, n, threads_for(float(n) * rows.shape[0] * p))
    query_of = np.concatenate([kept[lo][0] for lo in sorted(kept)])  # in query order, as one nonzero gives
    row_of = np.concatenate([kept[lo][1] for lo in sorted(kept)])
    exact = np.empty(len(query_of), dtype=np.float32)
    kernels.l1_float32_pairs(queries, rows, query_of, row_of, exact)
    order = np.lexsort((row_of, exact, query_of))  # by query, then distance, then row index
    firsts = np.searchsorted(query_of[order], np.arange(n))
    picked = firsts[:, None] + np.arange(k)[None, :]
    return row_of[order][picked]


def nearest_two(
    queries: np.ndarray, rows: np.ndarray, metric: Metric, chunk: int = 256, row_norms: np.ndarray | None = None,
    tile: int = 2048,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact nearest and second-nearest row of ``rows`` (M, D) for each query (N, D).

    The search that keeps an online vocabulary fast: L2 ranks with BLAS products
    (``|w|^2 - 2 q.w``, float32) of a chunk of queries against a tile of rows at a time,
    keeping the two best per query as it goes (a few MB that stay in cache, instead of an
    N x M matrix allocated and scanned again for every image), then recomputes the two
    winners' distances exactly in float64; Hamming uses OpenCV's SIMD popcount
    (``cv2.batchDistance``, several times faster than numpy's ``bitwise_count`` on packed
    rows). Ties go to the lower row index.

    :param row_norms: (M,) float32 ``|w|^2`` of the rows (``np.einsum("ij,ij->i", rows,
        rows)``), when the caller keeps them (an online vocabulary does); L2 only.
    :returns: ``(d1, d2, i1)``: (N,) float64 distances to the nearest and second nearest
        row, and (N,) int64 index of the nearest. With fewer than two rows the missing
        distances are ``inf`` and a missing index is -1.
    """
    with single_threaded_blas():
        return _nearest_two(np.atleast_2d(queries), rows, metric, chunk, row_norms, tile)


def _nearest_two(
    queries: np.ndarray, rows: np.ndarray, metric: Metric, chunk: int, row_norms: np.ndarray | None, tile: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n, m = len(queries), len(rows)
    d1 = np.full(n, np.inf)
    d2 = np.full(n, np.inf)
    i1 = np.full(n, -1, dtype=np.int64)
    if n == 0 or m == 0:
        return d1, d2, i1
    if queries.shape[1] != rows.shape[1]:
        raise CoreError(f"descriptor lengths differ: {queries.shape[1]} vs {rows.shape[1]}")
    if m == 1:
        d1[:] = pairwise(queries, rows, metric)[:, 0]
        i1[:] = 0
        return d1, d2, i1
    if metric == "hamming":
        if queries.dtype != np.uint8 or rows.dtype != np.uint8:
            raise CoreError("hamming distance needs uint8-packed binary descriptors")
        if queries.shape[1] % 8 == 0:  # whole 64-bit words: a compiled scan with the CPU's popcount
            packed = np.ascontiguousarray(queries).view(np.uint64)
            compiled().two_nearest_hamming(packed, np.ascontiguousarray(rows).view(np.uint64), d1, d2, i1)
            return d1, d2, i1
        import cv2  # only here: the rest of core stays numpy-only

        dist, index = cv2.batchDistance(
            np.ascontiguousarray(queries), np.ascontiguousarray(rows), cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2
        )
        return dist[:, 0].astype(np.float64), dist[:, 1].astype(np.float64), index[:, 0].astype(np.int64)
    if metric != "l2":
        full = pairwise(queries, rows, metric)
        order = np.argsort(full, axis=1, kind="stable")[:, :2]
        picked = np.take_along_axis(full, order, axis=1).astype(np.float64)
        return picked[:, 0], picked[:, 1], order[:, 0].astype(np.int64)
    rows32 = np.ascontiguousarray(rows, dtype=np.float32)
    norms = np.einsum("ij,ij->i", rows32, rows32) if row_norms is None else row_norms
    i2 = np.empty(n, dtype=np.int64)
    scores = np.empty((min(chunk, n), min(tile, m)), dtype=np.float32)
    for start in range(0, n, chunk):
        block = np.ascontiguousarray(queries[start : start + chunk], dtype=np.float32)
        i1[start : start + len(block)], i2[start : start + len(block)] = _two_lowest_scores(block, rows32, norms, scores)
    d1 = np.linalg.norm(queries.astype(np.float64) - rows[i1].astype(np.float64), axis=1)
    d2 = np.linalg.norm(queries.astype(np.float64) - rows[i2].astype(np.float64), axis=1)
    swap = d2 < d1  # float32 ranking can swap near-ties; the exact distances decide
    d1[swap], d2[swap] = d2[swap], d1[swap].copy()
    i1 = np.where(swap, i2, i1)
    return d1, d2, i1


def _two_lowest_scores(
    block: np.ndarray, rows: np.ndarray, norms: np.ndarray, scores: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per query of ``block``, the rows with the lowest and second-lowest ``|w|^2 - 2 q.w``
    (float32; ties to the lower row), a tile of rows at a time through ``scores``."""
    q, tile = len(block), scores.shape[1]
    local = np.arange(q)
    best = np.full(q, np.inf, dtype=np.float32)
    second = np.full(q, np.inf, dtype=np.float32)
    first_row = np.zeros(q, dtype=np.int64)
    second_row = np.zeros(q, dtype=np.int64)
    for lo in range(0, len(rows), tile):
        hi = min(lo + tile, len(rows))
        s = scores[:q, : hi - lo]
        np.matmul(block, rows[lo:hi].T, out=s)
        # |q|^2 is the same for every row of a query: leave it out of the ranking
        np.subtract(norms[lo:hi], np.multiply(s, 2.0, out=s), out=s)
        t1 = np.argmin(s, axis=1)
        v1 = s[local, t1]
        s[local, t1] = np.inf
        t2 = np.argmin(s, axis=1)
        v2 = s[local, t2]
        # merge with the two best of the earlier tiles, whose rows come first (they win ties)
        new = v1 < best
        second_row = np.where(new, np.where(v2 < best, t2 + lo, first_row), np.where(v1 < second, t1 + lo, second_row))
        second = np.where(new, np.minimum(v2, best), np.minimum(v1, second))
        first_row = np.where(new, t1 + lo, first_row)
        best = np.where(new, v1, best)
    return first_row, second_row
