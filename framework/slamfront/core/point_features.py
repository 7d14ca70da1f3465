"""Point Feature Histograms (PFH, Rusu et al. 2008) on NumPy arrays, as PCL computes them.

For every pair of points in a neighbourhood, the Darboux frame ``u = n_s``,
``v = (p_t - p_s) x u / |.|``, ``w = u x v`` at the source point gives three angles
(PCL's ``computePairFeatures``; the source is the point whose normal makes the smaller
angle with the line joining them)::

    theta = atan2(w . n_t, u . n_t)      in [-pi, pi]
    alpha = v . n_t                      in [-1, 1]
    phi   = u . (p_t - p_s) / |p_t - p_s| in [-1, 1]

PCL's ``PFHSignature125`` splits each into 5 bins and counts every pair of the
neighbourhood (``k (k - 1) / 2`` pairs, the point itself included) in one of the
``5 ** 3`` joint bins, each pair adding ``100 / pairs``: a histogram in percent. The
distance is not used. Degenerate pairs (coincident points, normal along the joining line)
get all-zero features, as in PCL, and land in the centre bin.

Everything here is vectorised: the pairs of many neighbourhoods are processed as one
array, in chunks that bound memory.
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError

PFH_SPLITS = 5
"""Bins per angle (PCL's ``nr_subdiv``)."""
PFH_BINS = PFH_SPLITS**3
"""Length of a PFH signature: 125."""
_PAIR_CHUNK = 1 << 19
"""Pairs processed at once (bounds the temporary arrays to about 150 MB)."""


def hybrid_neighbours(points: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
    """The ``max_nn`` nearest points within ``radius`` of each point, nearest first.

    The same neighbourhood Open3D's ``KDTreeSearchParamHybrid(radius, max_nn)`` gives
    (and so its FPFH uses); each point is its own first neighbour.

    :returns: ``(N, max_nn)`` int64 indices, ``-1`` where a point has fewer neighbours.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise CoreError(f"points must be (N, 3), got {points.shape}")
    if radius <= 0 or max_nn < 1:
        raise CoreError(f"radius must be > 0 and max_nn >= 1, got {radius}, {max_nn}")
    if len(points) == 0:
        return np.empty((0, max_nn), dtype=np.int64)
    k = min(max_nn, len(points))
    from scipy.spatial import cKDTree  # ~0.7 s to import: when clouds are registered, not when listed

    _, index = cKDTree(points).query(points, k=k, distance_upper_bound=radius, workers=-1)
    index = np.asarray(index, dtype=np.int64).reshape(len(points), k)
    index[index >= len(points)] = -1
    if k < max_nn:
        index = np.hstack([index, np.full((len(points), max_nn - k), -1, dtype=np.int64)])
    return index


def pair_features(
    p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCL's ``computePairFeatures`` for arrays of pairs ``(..., 3)``.

    :returns: ``theta, alpha, phi, distance`` (PCL's f1, f2, f3, f4), each ``(...)``;
        all zero for degenerate pairs.
    """
    axis_first = [np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0) for a in (p1, n1, p2, n2)]
    return _pair_features(*axis_first)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _pair_features(
    p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pair_features` on coordinate-first arrays ``(3, ...)`` (contiguous per axis: faster)."""
    delta = p2 - p1
    distance = np.sqrt(_dot(delta, delta))
    safe = np.where(distance > 0, distance, 1.0)
    angle1 = _dot(n1, delta) / safe
    angle2 = _dot(n2, delta) / safe
    # the source is the end whose normal is closer to the joining line (PCL compares acos)
    swap = np.arccos(np.minimum(np.abs(angle1), 1.0)) > np.arccos(np.minimum(np.abs(angle2), 1.0))
    source_normal = np.where(swap, n2, n1)
    target_normal = np.where(swap, n1, n2)
    line = np.where(swap, -delta, delta)
    phi = np.where(swap, -angle2, angle1)
    v = _cross(line, source_normal)
    v_norm = np.sqrt(_dot(v, v))
    v /= np.where(v_norm > 0, v_norm, 1.0)
    w = _cross(source_normal, v)
    alpha = _dot(v, target_normal)
    theta = np.arctan2(_dot(w, target_normal), _dot(source_normal, target_normal))
    degenerate = (distance == 0) | (v_norm == 0)
    if degenerate.any():
        theta[degenerate] = alpha[degenerate] = phi[degenerate] = distance[degenerate] = 0.0
    return theta, alpha, phi, distance


def pfh_bin(theta: np.ndarray, alpha: np.ndarray, phi: np.ndarray, splits: int = PFH_SPLITS) -> np.ndarray:
    """Joint bin of each pair's three angles: ``b_theta + s * b_alpha + s**2 * b_phi`` (as PCL)."""
    b_theta = np.clip(np.floor(splits * ((theta + np.pi) * (1.0 / (2.0 * np.pi)))), 0, splits - 1)
    b_alpha = np.clip(np.floor(splits * ((alpha + 1.0) * 0.5)), 0, splits - 1)
    b_phi = np.clip(np.floor(splits * ((phi + 1.0) * 0.5)), 0, splits - 1)
    return (b_theta + splits * b_alpha + splits * splits * b_phi).astype(np.int64)


def pfh(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """PFH signatures (PCL's ``PFHSignature125``) of every point.

    :param points: ``(N, 3)``.
    :param normals: ``(N, 3)`` unit normals (oriented consistently, e.g. to the viewpoint).
    :param neighbours: ``(N, K)`` neighbourhood of each point (itself included), ``-1``
        padded, as :func:`hybrid_neighbours` returns.
    :returns: ``(N, 125)`` float64 histograms in percent (each sums to 100), zero for a
        point with fewer than two neighbours.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    neighbours = np.asarray(neighbours, dtype=np.int64)
    n, k = neighbours.shape if neighbours.ndim == 2 else (-1, -1)
    if points.shape != normals.shape or points.ndim != 2 or points.shape[1] != 3 or n != len(points):
        raise CoreError(
            f"pfh needs points (N, 3), normals (N, 3) and neighbours (N, K); got "
            f"{points.shape}, {normals.shape}, {neighbours.shape}"
        )
    histograms = np.zeros((n, PFH_BINS), dtype=np.float64)
    if n == 0 or k < 2:
        return histograms
    # PCL's loop order: for i_idx, for j_idx < i_idx: features(p[i_idx], p[j_idx])
    later, earlier = np.triu_indices(k, 1)[::-1]
    points_t, normals_t = np.ascontiguousarray(points.T), np.ascontiguousarray(normals.T)
    counts = np.sum(neighbours >= 0, axis=1)
    pair_counts = counts * (counts - 1) // 2
    increment = np.divide(100.0, pair_counts, out=np.zeros(n), where=pair_counts > 0)
    chunk = max(1, _PAIR_CHUNK // len(later))
    for start in range(0, n, chunk):
        rows = np.arange(start, min(start + chunk, n))
        first = neighbours[rows][:, later]
        second = neighbours[rows][:, earlier]
        valid = (first >= 0) & (second >= 0)
        owner = np.broadcast_to(rows[:, None], valid.shape)[valid]
        i, j = first[valid], second[valid]
        theta, alpha, phi, _ = _pair_features(points_t[:, i], normals_t[:, i], points_t[:, j], normals_t[:, j])
        flat = (owner - start) * PFH_BINS + pfh_bin(theta, alpha, phi)
        votes = np.bincount(flat, minlength=len(rows) * PFH_BINS).reshape(len(rows), PFH_BINS)
        histograms[rows] = votes * increment[rows, None]
    return histograms
