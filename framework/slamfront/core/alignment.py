"""Aligning point sets and the absolute trajectory error (ATE), in 2-D or 3-D.

Umeyama, "Least-squares estimation of transformation parameters between two point
patterns", IEEE TPAMI 13(4), 1991: the similarity (or rigid motion) ``dst ~ s R src + t``
minimising the summed squared distances, in closed form (eqs. 38-42). Horn's 1987
quaternion method gives the same rigid motion in 3-D; Umeyama's SVD form works in any
dimension and guards against reflections. The ATE (Sturm et al., IROS 2012) is the RMSE
of the positions after that alignment.
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError


def _points(array: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(array, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise CoreError(f"{name} must be an (N, 2) or (N, 3) array of positions, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise CoreError(f"{name} has non-finite values")
    return array


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``R, t, s`` minimising ``sum ||dst_i - (s R src_i + t)||^2``.

    :param src: (N, d) points, d = 2 or 3.
    :param dst: (N, d) corresponding points.
    :param with_scale: estimate ``s`` (a similarity, for monocular trajectories);
        otherwise ``s = 1`` (a rigid motion).
    :returns: ``R`` (d, d) proper rotation, ``t`` (d,), ``s`` > 0.
    :raises CoreError: shapes differ, fewer than 2 points, or ``src`` has no spread.
    """
    src, dst = _points(src, "src"), _points(dst, "dst")
    if src.shape != dst.shape:
        raise CoreError(f"src {src.shape} and dst {dst.shape} must have the same shape")
    n, d = src.shape
    if n < 2:
        raise CoreError(f"alignment needs at least 2 corresponding points, got {n}")
    mean_src, mean_dst = src.mean(axis=0), dst.mean(axis=0)
    centred_src, centred_dst = src - mean_src, dst - mean_dst
    variance_src = float(np.mean(np.sum(centred_src**2, axis=1)))
    if variance_src < 1e-18:
        raise CoreError("alignment is undefined: all source points coincide")
    covariance = centred_dst.T @ centred_src / n  # eq. 38
    u, singular, vt = np.linalg.svd(covariance)
    sign = np.ones(d)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # eq. 39: a reflection would fit better
        sign[-1] = -1.0
    rotation = u @ np.diag(sign) @ vt  # eq. 40
    scale = float(np.sum(singular * sign) / variance_src) if with_scale else 1.0  # eq. 42
    translation = mean_dst - scale * rotation @ mean_src  # eq. 41
    return rotation, translation, scale


def transform_points(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """``s R p + t`` for each row ``p`` of (N, d) ``points``."""
    return scale * np.asarray(points, dtype=np.float64) @ np.asarray(rotation).T + np.asarray(translation)


def ate_rmse(estimate: np.ndarray, ground_truth: np.ndarray, with_scale: bool = False, align: bool = True) -> float:
    """Absolute trajectory error: RMSE of positions after aligning ``estimate`` to ``ground_truth``.

    :param estimate: (N, d) estimated positions.
    :param ground_truth: (N, d) true positions of the same poses (same units, metres).
    :param with_scale: align with a similarity instead of a rigid motion.
    :param align: False compares the positions as given (a shared, fixed frame).
    :returns: RMSE in the units of ``ground_truth``.
    """
    estimate, ground_truth = _points(estimate, "estimate"), _points(ground_truth, "ground_truth")
    if estimate.shape != ground_truth.shape:
        raise CoreError(f"estimate {estimate.shape} and ground truth {ground_truth.shape} must have the same shape")
    if align:
        estimate = transform_points(estimate, *umeyama(estimate, ground_truth, with_scale))
    return float(np.sqrt(np.mean(np.sum((estimate - ground_truth) ** 2, axis=1))))
