"""Closed-form alignment of two point sets (Umeyama 1991; Horn 1987 for the rigid case).

Used to align an estimated trajectory to its ground truth before the absolute
trajectory error is computed, since the two are expressed in arbitrary frames.
"""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """The similarity ``dst ~ s * R @ src + t`` minimising the squared error (Umeyama 1991).

    :param src: (N, d) points, d = 2 or 3.
    :param dst: (N, d) corresponding points.
    :param with_scale: estimate ``s`` (Sim(d)); otherwise ``s = 1`` (SE(d), Horn's problem).
    :returns: ``R`` (d, d) proper rotation, ``t`` (d,), ``s``.
    :raises CoreError: shapes differ, fewer than 2 points, or all source points coincide
        (the rotation is then undetermined).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape != dst.shape or src.shape[1] not in (2, 3):
        raise CoreError(f"umeyama needs two (N, 2) or (N, 3) arrays of one shape, got {src.shape} and {dst.shape}")
    n, d = src.shape
    if n < 2:
        raise CoreError(f"umeyama needs at least 2 point pairs, got {n}")
    mean_src, mean_dst = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - mean_src, dst - mean_dst
    variance_src = float((src_c**2).sum() / n)
    if variance_src < 1e-18:
        raise CoreError("umeyama: all source points coincide, the alignment is undetermined")
    covariance = dst_c.T @ src_c / n  # eq. 38
    u, singular, vt = np.linalg.svd(covariance)
    signs = np.ones(d)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # eq. 39: a reflection would fit better; forbid it
        signs[-1] = -1.0
    rotation = u @ np.diag(signs) @ vt  # eq. 40
    scale = float((singular * signs).sum() / variance_src) if with_scale else 1.0  # eq. 42
    translation = mean_dst - scale * rotation @ mean_src  # eq. 41
    return rotation, translation, scale


def apply(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """(N, d) points mapped by ``s * R @ p + t`` (a new array)."""
    return scale * np.asarray(points, dtype=np.float64) @ np.asarray(rotation).T + np.asarray(translation)


def ate_rmse(est: np.ndarray, gt: np.ndarray, with_scale: bool = False) -> float:
    """Root-mean-square position error after aligning ``est`` (N, d) onto ``gt`` (N, d).

    The translational ATE of Sturm et al. 2012 (eq. 4.5 of Barbosa 2017) for already
    associated positions.
    """
    rotation, translation, scale = umeyama(est, gt, with_scale)
    residual = apply(est, rotation, translation, scale) - np.asarray(gt, dtype=np.float64)
    return float(np.sqrt((residual**2).sum(axis=1).mean()))
