"""Geometric verification of a loop closure: PnP on feature matches, using depth.

The matched (older) frame's keypoints are lifted to 3-D with its depth image; the
query frame's keypoints matched to them give 2-D/3-D correspondences; RANSAC PnP
(``cv2.solvePnPRansac``) then a Levenberg-Marquardt refinement on the inliers give the
query camera's pose in the matched camera's frame. Features come from
:mod:`slamfront.local_features` (any descriptor type); functions over arrays only: the
back end calls them and owns the bookkeeping. Swapping in another matcher means
replacing :func:`match_features`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import Field

from slamfront import Camera, PluginConfig
from slamfront.core import geometry
from slamfront.local_features import DescriptorType


class PnPConfig(PluginConfig):
    """PnP verification settings."""

    descriptor: DescriptorType = Field(
        "orb", description="local features computed per frame when the descriptor stage gives none"
    )
    n_features: int = Field(1000, ge=10, description="keypoints per frame, strongest first")
    ratio: float = Field(0.8, gt=0, le=1, description="Lowe's ratio test on the two nearest descriptors")
    reprojection_px: float = Field(3.0, gt=0, description="RANSAC inlier threshold, pixels")
    iterations: int = Field(500, ge=10, description="RANSAC iterations")
    min_inliers: int = Field(20, ge=4, description="fewer inliers: the closure is not verified")
    min_inlier_ratio: float = Field(0.3, ge=0, le=1, description="... or fewer inliers per match than this")
    max_translation_m: float = Field(20.0, gt=0, description="a verified motion longer than this is refused")
    seed: int = Field(0, description="OpenCV RNG seed for RANSAC (results are reproducible)")


@dataclass(frozen=True)
class FrameFeatures:
    """Keypoints of one frame, with their 3-D points in its camera where depth is known.

    :ivar keypoints: (N, 2) float32 pixel x, y.
    :ivar descriptors: (N, D) uint8 (binary, Hamming) or float32 (L2).
    :ivar points: (N, 3) float64 camera coordinates (metres; NaN without depth).
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    points: np.ndarray


@dataclass(frozen=True)
class Verification:
    """The outcome: ``transform`` (4, 4) pose of the query camera in the matched camera's
    frame when verified, else None and ``reason`` says why."""

    transform: np.ndarray | None
    inliers: int
    matches: int
    reason: str


def lift(keypoints: np.ndarray, depth: np.ndarray | None, camera: Camera) -> np.ndarray:
    """(N, 3) camera-frame points of keypoints from a depth image in metres (NaN where 0)."""
    points = np.full((len(keypoints), 3), np.nan)
    if depth is None or len(keypoints) == 0:
        return points
    height, width = depth.shape
    u = np.clip(np.round(keypoints[:, 0]).astype(int), 0, width - 1)
    v = np.clip(np.round(keypoints[:, 1]).astype(int), 0, height - 1)
    z = depth[v, u].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    points[valid, 0] = (keypoints[valid, 0] - camera.cx) * z[valid] / camera.fx
    points[valid, 1] = (keypoints[valid, 1] - camera.cy) * z[valid] / camera.fy
    points[valid, 2] = z[valid]
    return points


def match_features(query: np.ndarray, reference: np.ndarray, ratio: float) -> np.ndarray:
    """(K, 2) index pairs (query, reference) passing the ratio test; Hamming for uint8."""
    if len(query) < 2 or len(reference) < 2:
        return np.empty((0, 2), dtype=np.int64)
    norm = cv2.NORM_HAMMING if query.dtype == np.uint8 else cv2.NORM_L2
    pairs = cv2.BFMatcher(norm).knnMatch(query, reference.astype(query.dtype), k=2)
    good = [(m[0].queryIdx, m[0].trainIdx) for m in pairs if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    return np.array(good, dtype=np.int64).reshape(-1, 2)


def verify(reference: FrameFeatures, query: FrameFeatures, camera: Camera, config: PnPConfig) -> Verification:
    """The query camera's pose in the reference camera's frame, by RANSAC PnP.

    :param reference: the older frame (its ``points`` need depth).
    :param query: the frame that closes the loop (its keypoints are enough).
    """
    pairs = match_features(query.descriptors, reference.descriptors, config.ratio)
    if len(pairs):
        pairs = pairs[np.all(np.isfinite(reference.points[pairs[:, 1]]), axis=1)]
    if len(pairs) < max(config.min_inliers, 6):
        return Verification(None, 0, len(pairs), f"{len(pairs)} matches with depth (need {config.min_inliers})")
    object_points = reference.points[pairs[:, 1]].astype(np.float64)
    image_points = query.keypoints[pairs[:, 0]].astype(np.float64)
    matrix = camera.matrix.astype(np.float64)
    cv2.setRNGSeed(config.seed)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        object_points, image_points, matrix, None, iterationsCount=config.iterations,
        reprojectionError=config.reprojection_px, confidence=0.999,
    )
    n_inliers = 0 if inliers is None else len(inliers)
    if not ok or n_inliers < config.min_inliers or n_inliers < config.min_inlier_ratio * len(pairs):
        return Verification(None, n_inliers, len(pairs), f"PnP: {n_inliers} inliers of {len(pairs)} matches")
    chosen = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(object_points[chosen], image_points[chosen], matrix, None, rvec, tvec)
    rotation, _ = cv2.Rodrigues(rvec)
    query_from_reference = geometry.se3(tvec.ravel(), rotation)  # maps reference-camera points into the query camera
    transform = geometry.invert(query_from_reference)
    distance = float(np.linalg.norm(transform[:3, 3]))
    if distance > config.max_translation_m:
        return Verification(None, n_inliers, len(pairs), f"PnP motion {distance:.1f} m exceeds {config.max_translation_m} m")
    return Verification(transform, n_inliers, len(pairs), f"PnP: {n_inliers} inliers of {len(pairs)} matches")
