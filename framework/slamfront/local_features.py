"""Local features with OpenCV: keypoints and descriptors, with the distance they need.

One table, :data:`DESCRIPTORS`, says for each descriptor type how OpenCV builds it,
whether it is binary (compared by Hamming distance on packed bits) or float (L2), its
length, and whether it needs a separate keypoint detector (BRIEF and FREAK only
describe). The loop detectors, the localizer and the descriptor evaluation share this
module through the ``local_features`` descriptor plugin.

SURF is patented; OpenCV's wheels (contrib included) are built without
``OPENCV_ENABLE_NONFREE``, so it is not available. SIFT/RootSIFT or KAZE replace it for
float descriptors, ORB/BRISK/AKAZE for binary ones.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Annotated, Literal

import numpy as np
from pydantic import BeforeValidator

from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import OpenCV

DescriptorType = Literal["sift", "rootsift", "orb", "brisk", "akaze", "kaze", "brief", "freak"]
DetectorType = Literal["native", "fast", "agast", "gftt", "orb", "sift", "brisk"]

SURF_UNAVAILABLE = (
    "SURF is patented and not in OpenCV's wheels (built without OPENCV_ENABLE_NONFREE); "
    "use sift, rootsift or kaze for float descriptors, orb, brisk or akaze for binary ones"
)


def _refuse_surf(value: object) -> object:
    if isinstance(value, str) and value.lower() == "surf":
        raise ValueError(SURF_UNAVAILABLE)
    return value


DescriptorName = Annotated[DescriptorType, BeforeValidator(_refuse_surf)]
"""A descriptor type in a plugin config; asking for SURF gets the reason it is missing."""


@dataclass(frozen=True)
class DescriptorSpec:
    """How to build one descriptor type and compare its vectors."""

    create: Callable[[int], cv2.Feature2D]
    """Builds the OpenCV object for at most ``n`` features."""
    metric: Literal["l2", "hamming"]
    length: int
    """Floats per descriptor, or bytes for binary ones."""
    dtype: type
    needs_detector: bool = False
    """True for describe-only methods (BRIEF, FREAK)."""


def _xfeatures(name: str) -> Callable[..., cv2.Feature2D]:
    """An OpenCV contrib constructor (in cv2.xfeatures2d since OpenCV 5, in cv2 before)."""
    module = getattr(cv2, "xfeatures2d", None)
    return getattr(module, name, None) or getattr(cv2, name)


DESCRIPTORS: Mapping[str, DescriptorSpec] = MappingProxyType(
    {
        "sift": DescriptorSpec(lambda n: cv2.SIFT_create(nfeatures=n), "l2", 128, np.float32),
        "rootsift": DescriptorSpec(lambda n: cv2.SIFT_create(nfeatures=n), "l2", 128, np.float32),
        "orb": DescriptorSpec(lambda n: cv2.ORB_create(nfeatures=n), "hamming", 32, np.uint8),
        "brisk": DescriptorSpec(lambda n: _xfeatures("BRISK_create")(), "hamming", 64, np.uint8),
        "akaze": DescriptorSpec(lambda n: _xfeatures("AKAZE_create")(), "hamming", 61, np.uint8),
        "kaze": DescriptorSpec(lambda n: _xfeatures("KAZE_create")(), "l2", 64, np.float32),
        "brief": DescriptorSpec(
            lambda n: _xfeatures("BriefDescriptorExtractor_create")(32), "hamming", 32, np.uint8, True
        ),
        "freak": DescriptorSpec(lambda n: _xfeatures("FREAK_create")(), "hamming", 64, np.uint8, True),
    }
)

DETECTORS: Mapping[str, Callable[[int], cv2.Feature2D]] = MappingProxyType(
    {
        "fast": lambda n: cv2.FastFeatureDetector_create(threshold=20),
        "agast": lambda n: _xfeatures("AgastFeatureDetector_create")(),
        "gftt": lambda n: cv2.GFTTDetector_create(maxCorners=n, qualityLevel=0.01, minDistance=5),
        "orb": lambda n: cv2.ORB_create(nfeatures=n),
        "sift": lambda n: cv2.SIFT_create(nfeatures=n),
        "brisk": lambda n: _xfeatures("BRISK_create")(),
    }
)


@dataclass(frozen=True)
class LocalFeatures:
    """Keypoints and descriptors of one image.

    :ivar keypoints: (N, 2) float32 pixel coordinates x, y.
    :ivar info: (N, 4) float32 size, angle (degrees), response, octave.
    :ivar descriptors: (N, D) float32, or uint8 packed bits when ``metric`` is hamming.
    """

    keypoints: np.ndarray
    info: np.ndarray
    descriptors: np.ndarray
    metric: Literal["l2", "hamming"]

    def __len__(self) -> int:
        return len(self.keypoints)


def _strongest_per_cell(
    keypoints: list[cv2.KeyPoint], shape: tuple[int, int], grid: tuple[int, int], limit: int
) -> list[cv2.KeyPoint]:
    """Keep the strongest keypoints of each grid cell so features spread over the image."""
    rows, cols = grid
    per_cell = max(1, limit // (rows * cols))
    height, width = shape
    cells: dict[tuple[int, int], list[cv2.KeyPoint]] = {}
    for kp in keypoints:
        cell = (min(int(kp.pt[1] * rows / height), rows - 1), min(int(kp.pt[0] * cols / width), cols - 1))
        cells.setdefault(cell, []).append(kp)
    kept = []
    for members in cells.values():
        members.sort(key=lambda k: -k.response)
        kept.extend(members[:per_cell])
    kept.sort(key=lambda k: -k.response)
    return kept[:limit]


class LocalFeatureExtractor:
    """Detects and describes local features of grey images.

    :param descriptor: a key of :data:`DESCRIPTORS`.
    :param detector: ``native`` (the descriptor's own detector) or a key of
        :data:`DETECTORS`; BRIEF and FREAK need a named one.
    :param max_features: keep at most this many, strongest first.
    :param grid: (rows, cols) bucketing so features cover the image; None keeps the
        globally strongest.
    :param scale: resize the image by this factor before detection (e.g. 4 for 64x32
        thumbnails, where detectors find almost nothing at native size); keypoints and
        sizes are reported in the original image's pixels.
    """

    def __init__(
        self,
        descriptor: DescriptorType,
        detector: DetectorType = "native",
        max_features: int = 1000,
        grid: tuple[int, int] | None = None,
        scale: float = 1.0,
    ) -> None:
        if scale <= 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        self.spec = DESCRIPTORS[descriptor]
        self.descriptor_type = descriptor
        self.max_features = max_features
        self.grid = grid
        self.scale = scale
        oversample = max_features * 4 if grid else max_features
        self._describer = self.spec.create(oversample)
        if detector == "native":
            if self.spec.needs_detector:
                raise ValueError(f"{descriptor} only describes keypoints: name a detector (e.g. fast)")
            self._detector = self._describer
        else:
            self._detector = DETECTORS[detector](oversample)

    def extract(self, grey: np.ndarray) -> LocalFeatures:
        """Features of a uint8 ``(H, W)`` image (an image with none gives N = 0)."""
        if self.scale != 1.0:
            interpolation = cv2.INTER_LINEAR if self.scale > 1 else cv2.INTER_AREA
            grey = cv2.resize(grey, None, fx=self.scale, fy=self.scale, interpolation=interpolation)
        keypoints = list(self._detector.detect(grey, None))
        if self.grid:
            keypoints = _strongest_per_cell(keypoints, grey.shape[:2], self.grid, self.max_features)
        else:
            keypoints = sorted(keypoints, key=lambda k: -k.response)[: self.max_features]
        descriptors = None
        if keypoints:
            keypoints, descriptors = self._describer.compute(grey, keypoints)
        if descriptors is None or len(keypoints) == 0:
            return self._empty()
        # compute() may drop keypoints or re-score them (ORB): order strongest first again
        order = np.argsort([-kp.response for kp in keypoints], kind="stable")
        keypoints = [keypoints[i] for i in order]
        descriptors = descriptors[order].astype(self.spec.dtype, copy=False)
        if self.descriptor_type == "rootsift":
            descriptors = _root_sift(descriptors)
        # back to the original pixels: the centre of pixel x at this scale is (x + 0.5) / s - 0.5
        points = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
        points = (points + 0.5) / self.scale - 0.5 if self.scale != 1.0 else points
        info = np.array(
            [(kp.size / self.scale, kp.angle, kp.response, kp.octave) for kp in keypoints], dtype=np.float32
        )
        return LocalFeatures(points, info.reshape(-1, 4), np.ascontiguousarray(descriptors), self.spec.metric)

    def _empty(self) -> LocalFeatures:
        return LocalFeatures(
            np.zeros((0, 2), np.float32),
            np.zeros((0, 4), np.float32),
            np.zeros((0, self.spec.length), self.spec.dtype),
            self.spec.metric,
        )


def _root_sift(descriptors: np.ndarray) -> np.ndarray:
    """RootSIFT (Arandjelovic & Zisserman 2012): L1-normalise, then square root.

    L2 distance between RootSIFT vectors equals the Hellinger kernel distance of SIFT.
    """
    l1 = np.abs(descriptors).sum(axis=1, keepdims=True)
    return np.sqrt(descriptors / np.maximum(l1, 1e-12)).astype(np.float32)
