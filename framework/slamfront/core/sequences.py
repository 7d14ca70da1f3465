"""Sequence alignment on distance matrices: slide a query sequence along a longer one.

Used by sequence-based loop detectors (template matching of Rodrigues 2019, eq. 3.10). Pure
functions over arrays.
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError


def alignment_costs(distances: np.ndarray) -> np.ndarray:
    """Cost of every placement of a query sequence inside a longer candidate sequence.

    :param distances: (n, m) float, ``distances[k, i]`` between query element k and
        candidate element i, with ``m >= n``.
    :returns: (m - n + 1,) float64, ``cost[j] = sum_k distances[k, j + k]``: the query
        laid over candidate elements ``j .. j + n - 1``.
    :raises CoreError: the candidate is shorter than the query, or either is empty.
    """
    distances = np.asarray(distances, dtype=np.float64)
    if distances.ndim != 2 or distances.shape[0] == 0:
        raise CoreError(f"need an (n, m) matrix with n >= 1, got shape {distances.shape}")
    n, m = distances.shape
    if m < n:
        raise CoreError(f"the candidate sequence ({m}) is shorter than the query ({n})")
    offsets = np.arange(m - n + 1)[:, None] + np.arange(n)[None, :]
    return distances[np.arange(n)[None, :], offsets].sum(axis=1)


def best_alignment(distances: np.ndarray) -> tuple[int, float]:
    """The offset with the lowest :func:`alignment_costs` (the first one on ties) and its cost."""
    costs = alignment_costs(distances)
    best = int(np.argmin(costs))
    return best, float(costs[best])
