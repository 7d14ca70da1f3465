"""Removing lens distortion, so every stage can treat a frame as a pinhole image.

Recordings give intrinsics with a distortion model (ROS ``CameraInfo``, EuRoC's
``sensor.yaml``); slamfront's stages (PnP, back-projection of depth) assume a pinhole
camera. A source that knows the distortion undistorts each image (and depth, with
nearest-neighbour sampling so no depth is invented between surfaces) onto the same
intrinsics ``K``, once per frame with maps computed once.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slamfront.errors import DataError
from slamfront.frame import Camera
from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

RADIAL_TANGENTIAL = ("plumb_bob", "radtan", "radial-tangential", "rational_polynomial")
FISHEYE = ("equidistant", "fisheye", "kannala_brandt")


@dataclass
class Undistortion:
    """Maps that undistort images of ``camera`` with ``model`` and ``coefficients``.

    :param model: ``plumb_bob``/``radtan``/``rational_polynomial`` (OpenCV's k1 k2 p1 p2
        [k3 ...]) or ``equidistant``/``fisheye`` (k1 k2 k3 k4).
    """

    camera: Camera
    model: str
    coefficients: np.ndarray
    _maps: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False)

    @staticmethod
    def needed(model: str, coefficients: np.ndarray) -> bool:
        """Whether the coefficients distort at all (drivers publish zeros for rectified images)."""
        return bool(len(coefficients)) and bool(np.any(np.asarray(coefficients, dtype=np.float64) != 0)) and bool(model)

    def _build(self) -> tuple[np.ndarray, np.ndarray]:
        k = self.camera.matrix
        size = (self.camera.width, self.camera.height)
        model = self.model.lower()
        d = np.asarray(self.coefficients, dtype=np.float64)
        if model in RADIAL_TANGENTIAL:
            return cv2.initUndistortRectifyMap(k, d, None, k, size, cv2.CV_32FC1)
        if model in FISHEYE:
            if len(d) < 4:
                raise DataError(f"the {self.model} distortion model needs 4 coefficients, got {len(d)}")
            return cv2.fisheye.initUndistortRectifyMap(k, d[:4], np.eye(3), k, size, cv2.CV_32FC1)
        raise DataError(
            f"unsupported distortion model {self.model!r} (supported: {', '.join(RADIAL_TANGENTIAL + FISHEYE)}); "
            "set the source's `undistort: false` to use the images as they are"
        )

    def image(self, pixels: np.ndarray) -> np.ndarray:
        """An undistorted colour or grey image (bilinear)."""
        if self._maps is None:
            self._maps = self._build()
        return cv2.remap(pixels, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """An undistorted depth image (nearest neighbour: never a depth between two surfaces)."""
        if self._maps is None:
            self._maps = self._build()
        return cv2.remap(depth, *self._maps, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
