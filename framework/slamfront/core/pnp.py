"""Metric pose from 2-D/3-D correspondences: back-projection with depth, PnP + RANSAC.

Pixels are (x, y) with the origin at the centre of the top-left pixel; cameras follow
OpenCV (x right, y down, z forward). ``T_ab`` maps coordinates in frame b to frame a.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamfront.core.errors import CoreError
from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it


def backproject(
    keypoints: np.ndarray, depth: np.ndarray, camera_matrix: np.ndarray, max_relative_spread: float | None = 0.05
) -> np.ndarray:
    """(N, 3) float32 camera-frame points of (N, 2) pixel positions, from a depth map.

    :param depth: (H, W) metres along the optical axis; 0 or non-finite means unknown.
    :param max_relative_spread: keypoints sit on corners, often at a depth edge where the
        nearest pixel may belong to the background; a point is kept only when the depths
        of its 3x3 neighbourhood are all known and within this fraction of its own
        (None: no check, the nearest pixel's depth).
    :returns: NaN rows where the depth is unknown, inconsistent, or the keypoint lies
        outside the depth map.
    """
    keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    if depth.ndim != 2:
        raise CoreError(f"depth must be (H, W), got {depth.shape}")
    height, width = depth.shape
    columns = np.rint(keypoints[:, 0]).astype(np.int64)
    rows = np.rint(keypoints[:, 1]).astype(np.int64)
    inside = (columns >= 0) & (columns < width) & (rows >= 0) & (rows < height)
    z = np.full(len(keypoints), np.nan)
    z[inside] = depth[rows[inside], columns[inside]]
    z[~np.isfinite(z) | (z <= 0)] = np.nan
    if max_relative_spread is not None and len(z):
        window = np.full((len(z), 9), np.nan)
        for k, (dy, dx) in enumerate((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)):
            r, c = np.clip(rows + dy, 0, height - 1), np.clip(columns + dx, 0, width - 1)
            window[inside, k] = depth[r[inside], c[inside]]
        window[~np.isfinite(window) | (window <= 0)] = np.nan
        with np.errstate(invalid="ignore"):
            spread = (window.max(axis=1) - window.min(axis=1)) / z
        z[~(np.all(np.isfinite(window), axis=1) & (spread <= max_relative_spread))] = np.nan
    fx, fy = camera_matrix[0, 0], camera_matrix[1, 1]
    cx, cy = camera_matrix[0, 2], camera_matrix[1, 2]
    x = (keypoints[:, 0] - cx) / fx * z
    y = (keypoints[:, 1] - cy) / fy * z
    return np.stack([x, y, z], axis=1).astype(np.float32)


def _first_of_each(rows: np.ndarray) -> np.ndarray:
    """(N,) bool: True for the first occurrence of each distinct row of (N, D) ``rows``."""
    if len(rows) == 0:
        return np.zeros(0, dtype=bool)
    _, first = np.unique(rows, axis=0, return_index=True)
    keep = np.zeros(len(rows), dtype=bool)
    keep[first] = True
    return keep


@dataclass(frozen=True)
class PnpResult:
    """A PnP solution.

    :ivar transform: (4, 4) ``T_camera_object``: maps object points into the camera frame.
    :ivar inliers: (K,) indices of the correspondences consistent with it.
    :ivar reprojection_error_px: RMS reprojection error of the inliers.
    """

    transform: np.ndarray
    inliers: np.ndarray
    reprojection_error_px: float


def pnp_ransac(
    object_points: np.ndarray,
    image_points: np.ndarray,
    camera_matrix: np.ndarray,
    threshold_px: float = 3.0,
    confidence: float = 0.99,
    iterations: int = 300,
    min_inliers: int = 12,
) -> PnpResult | None:
    """Camera pose from (N, 3) object points seen at (N, 2) pixels (SQPnP in RANSAC, then LM).

    Rows with a NaN object point are ignored, and so are repeats: PnP needs one image
    point per object point, so only the first row of each distinct object point and of
    each distinct pixel is kept (give the rows best first). Never raises on the
    geometry of its input: too few distinct points, or points OpenCV finds degenerate
    (it asserts on nearly coincident ones), give None like any other failure.

    :returns: None when fewer than ``min_inliers`` correspondences agree on one pose.
    """
    object_points = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    image_points = np.asarray(image_points, dtype=np.float64).reshape(-1, 2)
    if len(object_points) != len(image_points):
        raise CoreError(f"{len(object_points)} object points but {len(image_points)} image points")
    usable = np.flatnonzero(np.all(np.isfinite(object_points), axis=1) & np.all(np.isfinite(image_points), axis=1))
    usable = usable[_first_of_each(object_points[usable]) & _first_of_each(image_points[usable])]
    if len(usable) < max(min_inliers, 4):
        return None
    obj, img = object_points[usable], image_points[usable]
    k = np.asarray(camera_matrix, dtype=np.float64)
    try:
        # SQPnP is exact for planar and non-planar points (EPnP and P3P are not: façades are planes)
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            obj, img, k, None, iterationsCount=iterations, reprojectionError=threshold_px,
            confidence=confidence, flags=cv2.SOLVEPNP_SQPNP,
        )
        if not ok or inliers is None or len(inliers) < min_inliers:
            return None
        inliers = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(obj[inliers], img[inliers], k, None, rvec, tvec)
    except cv2.error:
        # degenerate samples (nearly coincident or collinear points) trip OpenCV's assertions
        return None
    transform = np.eye(4)
    transform[:3, :3] = cv2.Rodrigues(rvec)[0]
    transform[:3, 3] = tvec.ravel()
    # reprojection does not see the sign of depth: a pose with the points behind it is no pose
    in_front = (obj[inliers] @ transform[:3, :3].T + transform[:3, 3])[:, 2] > 0
    inliers = inliers[in_front]
    if len(inliers) < min_inliers:
        return None
    projected, _ = cv2.projectPoints(obj[inliers], rvec, tvec, k, None)
    error = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img[inliers]) ** 2, axis=1))))
    return PnpResult(transform, usable[inliers], error)
