"""Two-image matching as Barbosa 2017 does it (§4.1.2): brute force, a distance threshold, RANSAC.

1. **Brute force**: every descriptor of image A takes its nearest descriptor in image B
   (L2 for float descriptors, Hamming for binary ones).
2. **Distance threshold**: matches farther than ``max_distance`` are dropped (the paper
   sets it per descriptor, empirically; :data:`DEFAULT_MAX_DISTANCE` holds ours).
3. **RANSAC** on the survivors: a fundamental matrix (any 3-D scene) or a homography
   (planar or distant scenes), or nothing.

The similarity of two images is the number of matches that survive all three. Loop
closure verification and the keyframe localizer share this module; plugins embed
:class:`MatchingConfig` in their own ``Config``.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

import numpy as np
from pydantic import Field

from slamfront.errors import PluginError
from slamfront.lazy import lazy_module
from slamfront.plugin import PluginConfig

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import OpenCV

Geometry = Literal["fundamental", "homography", "none"]

DEFAULT_MAX_DISTANCE = MappingProxyType(
    {
        # Set as the paper did, empirically (Barbosa 2017 §4.1.2), from measured distances on
        # real images (benchmarks/bench_descriptor_thresholds.py regenerates them): the 95th
        # percentile of the distances of correct matches (ratio test 0.8 + fundamental-matrix
        # RANSAC, frames at most 3 apart) in images/loop10 and the three RGB-D samples, 1,000
        # features per frame. Hamming distances are in bits (ORB/BRIEF 256, BRISK/FREAK 512,
        # AKAZE 486).
        "orb": 49.0,
        "brief": 45.0,
        "brisk": 109.0,
        "freak": 82.0,
        "akaze": 98.0,
        # L2: OpenCV's SIFT vectors have norm ~512; RootSIFT and KAZE are unit vectors.
        "sift": 250.0,
        "rootsift": 0.41,
        "kaze": 0.4,
    }
)

_NORMS = MappingProxyType({"l2": "NORM_L2", "hamming": "NORM_HAMMING"})  # cv2 names: OpenCV loads on first use
_MIN_POINTS = MappingProxyType({"fundamental": 8, "homography": 4, "none": 1})


class MatchingConfig(PluginConfig):
    """How two images are matched (embed in a plugin's ``Config``)."""

    max_distance: float | None = Field(
        None, gt=0, description="drop matches farther than this; None: the descriptor's default (DEFAULT_MAX_DISTANCE)"
    )
    ratio: float | None = Field(
        None, gt=0, le=1, description="also apply Lowe's ratio test (best / second best < ratio); None: off, as the paper"
    )
    cross_check: bool = Field(False, description="keep only mutual nearest neighbours")
    geometry: Geometry = Field("fundamental", description="RANSAC model: fundamental, homography, or none")
    ransac_threshold_px: float = Field(3.0, gt=0, description="RANSAC inlier distance in pixels")
    ransac_confidence: float = Field(0.99, gt=0, lt=1, description="RANSAC confidence")
    ransac_iterations: int = Field(1000, ge=1, description="RANSAC iteration limit")


def resolve_max_distance(config: MatchingConfig, descriptor_type: str | None) -> float:
    """The threshold to use: the configured one, else the descriptor type's default.

    :raises PluginError: neither is known (a descriptor plugin without a ``descriptor`` type).
    """
    if config.max_distance is not None:
        return config.max_distance
    if descriptor_type is not None and descriptor_type in DEFAULT_MAX_DISTANCE:
        return DEFAULT_MAX_DISTANCE[descriptor_type]
    raise PluginError(
        f"no default match distance for descriptor {descriptor_type!r}: set matching.max_distance "
        f"(defaults exist for {', '.join(DEFAULT_MAX_DISTANCE)})"
    )


@dataclass(frozen=True)
class TwoViewMatch:
    """The result of matching image A against image B.

    :ivar pairs: (K, 2) int32 indices (into A, into B) of the matches that survived everything.
    :ivar distances: (K,) float32 descriptor distances of those matches.
    :ivar n_putative: matches left after the distance threshold (and ratio/cross check).
    :ivar model: the RANSAC model (3, 3), or None.
    """

    pairs: np.ndarray
    distances: np.ndarray
    n_putative: int
    model: np.ndarray | None = None

    @property
    def inliers(self) -> int:
        """The similarity of the two images (Barbosa 2017): the number of surviving matches."""
        return len(self.pairs)


NO_MATCH = TwoViewMatch(np.zeros((0, 2), np.int32), np.zeros(0, np.float32), 0)


class Matcher:
    """Matches descriptor sets with one configuration (reuses OpenCV's brute-force matcher).

    :param config: the matching options.
    :param metric: ``l2`` or ``hamming`` (the descriptor's distance).
    :param max_distance: the resolved threshold (:func:`resolve_max_distance`).
    """

    def __init__(self, config: MatchingConfig, metric: str, max_distance: float) -> None:
        if metric not in _NORMS:
            raise PluginError(f"two-image matching needs l2 or hamming descriptors, got metric {metric!r}")
        self.config = config
        self.metric = metric
        self.max_distance = max_distance
        self._matcher = cv2.BFMatcher(getattr(cv2, _NORMS[metric]), crossCheck=config.cross_check and config.ratio is None)

    def putative(self, descriptors_a: np.ndarray, descriptors_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Brute-force nearest neighbours A -> B under the threshold: ((K, 2) pairs, (K,) distances)."""
        if len(descriptors_a) == 0 or len(descriptors_b) == 0:
            return NO_MATCH.pairs, NO_MATCH.distances
        c = self.config
        if c.ratio is None:
            found = self._matcher.match(descriptors_a, descriptors_b)
            pairs = np.array([(m.queryIdx, m.trainIdx) for m in found], dtype=np.int32).reshape(-1, 2)
            distances = np.array([m.distance for m in found], dtype=np.float32)
        else:
            knn = self._matcher.knnMatch(descriptors_a, descriptors_b, k=2)
            kept = [m[0] for m in knn if len(m) == 1 or (len(m) == 2 and m[0].distance < c.ratio * m[1].distance)]
            pairs = np.array([(m.queryIdx, m.trainIdx) for m in kept], dtype=np.int32).reshape(-1, 2)
            distances = np.array([m.distance for m in kept], dtype=np.float32)
            if c.cross_check and len(pairs):
                back = self._matcher.match(descriptors_b, descriptors_a)
                reverse = np.full(len(descriptors_b), -1, dtype=np.int64)
                for m in back:
                    reverse[m.queryIdx] = m.trainIdx
                mutual = reverse[pairs[:, 1]] == pairs[:, 0]
                pairs, distances = pairs[mutual], distances[mutual]
        close = distances <= self.max_distance
        return pairs[close], distances[close]

    def verify(self, points_a: np.ndarray, points_b: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """RANSAC inlier mask (K,) of ``pairs`` between (N, 2) / (M, 2) pixel positions, and the model."""
        c = self.config
        if c.geometry == "none":
            return np.ones(len(pairs), dtype=bool), None
        if len(pairs) < _MIN_POINTS[c.geometry]:
            return np.zeros(len(pairs), dtype=bool), None
        a = np.ascontiguousarray(points_a[pairs[:, 0]], dtype=np.float32)
        b = np.ascontiguousarray(points_b[pairs[:, 1]], dtype=np.float32)
        if c.geometry == "fundamental":
            model, mask = cv2.findFundamentalMat(
                a, b, cv2.FM_RANSAC, c.ransac_threshold_px, c.ransac_confidence, c.ransac_iterations
            )
        else:
            model, mask = cv2.findHomography(
                a, b, cv2.RANSAC, c.ransac_threshold_px, maxIters=c.ransac_iterations, confidence=c.ransac_confidence
            )
        if model is None or mask is None or model.shape != (3, 3):
            # OpenCV may return several stacked solutions or none for degenerate input
            return np.zeros(len(pairs), dtype=bool), None
        return mask.ravel().astype(bool), model

    def match(
        self, points_a: np.ndarray, descriptors_a: np.ndarray, points_b: np.ndarray, descriptors_b: np.ndarray
    ) -> TwoViewMatch:
        """Brute force, threshold, RANSAC: the paper's full two-image match."""
        pairs, distances = self.putative(descriptors_a, descriptors_b)
        if len(pairs) == 0:
            return NO_MATCH
        inlier, model = self.verify(points_a, points_b, pairs)
        return TwoViewMatch(pairs[inlier], distances[inlier], len(pairs), model)
