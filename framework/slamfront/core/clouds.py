"""Point clouds from depth images, and rigid transforms of point arrays."""

from __future__ import annotations

import numpy as np

from slamfront.core.errors import CoreError


def back_project(
    depth: np.ndarray,
    intrinsics: np.ndarray,
    min_depth: float = 0.0,
    max_depth: float = np.inf,
    stride: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame 3-D points of the valid pixels of a depth image.

    A pixel is valid when its depth is finite and in ``(min_depth, max_depth]``
    (0 means "no return" in slamfront). Camera axes as OpenCV: x right, y down, z forward.

    :param depth: ``(H, W)`` depth along the optical axis, metres.
    :param intrinsics: ``(3, 3)`` calibration matrix K.
    :param stride: use every ``stride``-th pixel in both directions.
    :returns: ``(N, 3)`` float64 points and ``(N, 2)`` int64 pixel rows/columns ``(v, u)``.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise CoreError(f"depth must be (H, W), got {depth.shape}")
    if stride < 1:
        raise CoreError(f"stride must be >= 1, got {stride}")
    k = np.asarray(intrinsics, dtype=np.float64)
    sampled = depth[::stride, ::stride].astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(sampled) & (sampled > max(min_depth, 0.0)) & (sampled <= max_depth)
    rows, cols = np.nonzero(valid)
    z = sampled[rows, cols]
    v, u = rows * stride, cols * stride
    points = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], axis=1)
    return points, np.stack([v, u], axis=1).astype(np.int64)


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a ``(4, 4)`` rigid transform to ``(N, 3)`` points (keeps their dtype)."""
    points = np.asarray(points)
    rotation = transform[:3, :3].astype(points.dtype, copy=False)
    translation = transform[:3, 3].astype(points.dtype, copy=False)
    return points @ rotation.T + translation


def depth_overlap(
    depth_a: np.ndarray,
    intrinsics_a: np.ndarray,
    depth_b: np.ndarray,
    intrinsics_b: np.ndarray,
    b_to_a: np.ndarray,
    tolerance: float = 0.05,
) -> float:
    """Share of view B's valid depth pixels that view A also sees, given the true motion.

    A point of B counts when, moved into A's camera by ``b_to_a``, it lies in front of A,
    inside A's image, and at A's measured depth there within ``tolerance`` (relative).
    0 means no surface is seen by both: no pairwise registration can succeed.
    """
    points, _ = back_project(depth_b, intrinsics_b)
    if len(points) == 0:
        return 0.0
    moved = transform_points(np.asarray(b_to_a, dtype=np.float64), points)
    k = np.asarray(intrinsics_a, dtype=np.float64)
    z = moved[:, 2]
    ahead = z > 1e-6
    safe_z = np.where(ahead, z, 1.0)
    u = np.round(k[0, 0] * moved[:, 0] / safe_z + k[0, 2]).astype(np.int64)
    v = np.round(k[1, 1] * moved[:, 1] / safe_z + k[1, 2]).astype(np.int64)
    height, width = np.asarray(depth_a).shape
    inside = ahead & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    seen = np.zeros(len(points), dtype=bool)
    measured = np.asarray(depth_a, dtype=np.float64)[v[inside], u[inside]]
    seen[inside] = (measured > 0) & (np.abs(measured - z[inside]) <= tolerance * z[inside])
    return float(seen.mean())
