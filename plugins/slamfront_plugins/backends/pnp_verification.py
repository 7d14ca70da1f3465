"""Geometric verification of a loop closure: PnP on feature matches, using depth.

The matched (older) frame's keypoints are lifted to 3-D with its depth image
(:func:`slamfront.core.pnp.backproject`); the query frame's keypoints matched to them
(:class:`slamfront.matching.Matcher`) give 2-D/3-D correspondences; RANSAC PnP then a
Levenberg-Marquardt refinement on the inliers (:func:`slamfront.core.pnp.pnp_ransac`)
give the query camera's pose in the matched camera's frame. The back end owns the
bookkeeping; this module only combines the shared pieces and says why a closure fails.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from slamfront import Camera, PluginConfig
from slamfront.core.geometry import invert
from slamfront.core.pnp import backproject, pnp_ransac
from slamfront.lazy import lazy_module
from slamfront.local_features import DescriptorType
from slamfront.matching import Matcher, MatchingConfig

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it


def _loop_matching() -> MatchingConfig:
    # PnP's RANSAC is the geometric check; Lowe's ratio removes the ambiguous matches of
    # repeated facades before it
    return MatchingConfig(ratio=0.8, geometry="none")


class PnPConfig(PluginConfig):
    """PnP verification settings."""

    descriptor: DescriptorType = Field(
        "orb", description="local features computed per frame when the descriptor stage gives none"
    )
    n_features: int = Field(1000, ge=10, description="keypoints per frame, strongest first")
    matching: MatchingConfig = Field(default_factory=_loop_matching, description="two-image matching")
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
    :ivar points: (N, 3) camera coordinates in metres (NaN without a reliable depth).
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
    """(N, 3) camera-frame points of keypoints from a depth image in metres (NaN rows without)."""
    if depth is None:
        return np.full((len(keypoints), 3), np.nan, dtype=np.float32)
    return backproject(keypoints, depth, camera.matrix)


def verify(
    reference: FrameFeatures, query: FrameFeatures, camera: Camera, matcher: Matcher, config: PnPConfig
) -> Verification:
    """The query camera's pose in the reference camera's frame, by RANSAC PnP.

    :param reference: the older frame (its ``points`` need depth).
    :param query: the frame that closes the loop (its keypoints are enough).
    """
    pairs = matcher.match(query.keypoints, query.descriptors, reference.keypoints, reference.descriptors).pairs
    pairs = pairs[np.all(np.isfinite(reference.points[pairs[:, 1]]), axis=1)] if len(pairs) else pairs
    if len(pairs) < config.min_inliers:
        return Verification(None, 0, len(pairs), f"{len(pairs)} matches with depth (need {config.min_inliers})")
    cv2.setRNGSeed(config.seed)  # OpenCV's RANSAC draws from its global RNG
    solution = pnp_ransac(
        reference.points[pairs[:, 1]], query.keypoints[pairs[:, 0]], camera.matrix,
        threshold_px=config.reprojection_px, iterations=config.iterations, min_inliers=config.min_inliers,
    )
    n_inliers = 0 if solution is None else len(solution.inliers)
    if solution is None or n_inliers < config.min_inlier_ratio * len(pairs):
        return Verification(None, n_inliers, len(pairs), f"PnP: {n_inliers} inliers of {len(pairs)} matches")
    transform = invert(solution.transform)  # the solution maps reference-camera points into the query camera
    distance = float(np.linalg.norm(transform[:3, 3]))
    if distance > config.max_translation_m:
        return Verification(None, n_inliers, len(pairs), f"PnP motion {distance:.1f} m exceeds {config.max_translation_m} m")
    return Verification(transform, n_inliers, len(pairs), f"PnP: {n_inliers} inliers of {len(pairs)} matches")
