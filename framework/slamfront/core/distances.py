"""Distances between descriptors, vectorised and chunked.

Metrics: ``l1`` (sum of absolute differences), ``l2`` (Euclidean), ``cosine``
(1 - cosine similarity) and ``hamming`` (differing bits of uint8-packed binary
descriptors).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from slamfront.core.errors import CoreError

Metric = Literal["l1", "l2", "cosine", "hamming"]
METRICS: tuple[Metric, ...] = ("l1", "l2", "cosine", "hamming")

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def pairwise(a: np.ndarray, b: np.ndarray, metric: Metric, chunk: int = 1024) -> np.ndarray:
    """(N, M) float32 distances between the rows of ``a`` (N, D) and ``b`` (M, D).

    Works in row chunks of ``a`` so memory stays at ``chunk * M * D`` for L1 and Hamming.
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
    out = np.empty((len(a), len(b)), dtype=np.float32)
    for start in range(0, len(a), chunk):
        block = a[start : start + chunk]
        if metric == "l1":
            out[start : start + chunk] = np.abs(block[:, None, :].astype(np.float32) - b[None, :, :]).sum(-1)
        else:
            if a.dtype != np.uint8 or b.dtype != np.uint8:
                raise CoreError("hamming distance needs uint8-packed binary descriptors")
            out[start : start + chunk] = _POPCOUNT[np.bitwise_xor(block[:, None, :], b[None, :, :])].sum(-1)
    return out


def to_one(query: np.ndarray, rows: np.ndarray, metric: Metric) -> np.ndarray:
    """(M,) distances from one descriptor ``query`` (D,) to each row of ``rows`` (M, D)."""
    return pairwise(query[None, :], rows, metric)[0]


def k_nearest(queries: np.ndarray, rows: np.ndarray, k: int, metric: Metric) -> np.ndarray:
    """(Q, min(k, M)) int64 indices of the ``k`` nearest rows to each query, nearest first.

    Ties are broken by row index (a stable sort of all distances), so the answer is
    deterministic. Queries are processed in chunks that keep the temporary arrays of
    L1/Hamming near 64 MB whatever Q and M.
    """
    queries = np.atleast_2d(queries)
    k = min(k, len(rows))
    chunk = max(1, (1 << 24) // max(1, rows.shape[0] * rows.shape[1]))
    out = np.empty((len(queries), k), dtype=np.int64)
    for start in range(0, len(queries), chunk):
        block = pairwise(queries[start : start + chunk], rows, metric, chunk=chunk)
        out[start : start + chunk] = np.argsort(block, axis=1, kind="stable")[:, :k]
    return out
