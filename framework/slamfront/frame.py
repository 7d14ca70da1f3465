"""The unit of data that flows through a run: one camera frame and what is known about it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Traversal = Literal["reference", "query", "stream"]
"""Which part of the run a frame belongs to.

``reference`` frames build a map, ``query`` frames are searched against it (paired
traversals, as in the published protocols), ``stream`` frames do both (a single
traversal that revisits places).
"""


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels, for an image of ``width`` x ``height``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 calibration matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by ``factor`` in both directions."""
        return Camera(
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            width=round(self.width * factor),
            height=round(self.height * factor),
        )


@dataclass(frozen=True)
class Frame:
    """One frame from a source.

    :param index: position in the run's stream, 0, 1, 2, ... in the order frames arrive.
        Every stage output and every ground truth refers to frames by this index.
    :param timestamp: seconds; strictly increasing within a run.
    :param image: ``(H, W)`` or ``(H, W, 3)`` uint8, colour in **RGB** order.
    :param traversal: see :data:`Traversal`.
    :param sequence_index: position within its traversal (the dataset's own numbering).
    :param name: where the frame came from (a file name), for messages and reports.
    :param depth: ``(H, W)`` float32 depth along the optical axis in metres, 0 where unknown.
    :param camera: intrinsics of ``image`` (and of ``depth``, which is registered to it).
    :param pose: ``(4, 4)`` ground-truth camera-to-world transform, if the source knows it.
    :param scene: which scene the frame shows ("" for a source's own). Frames of different
        scenes never show the same place: a localizer's map of one scene cannot hold a
        frame of another, which is how evaluation knows a frame is out of the map.
    """

    index: int
    timestamp: float
    image: np.ndarray
    traversal: Traversal = "stream"
    sequence_index: int = 0
    name: str = ""
    depth: np.ndarray | None = None
    camera: Camera | None = None
    pose: np.ndarray | None = None
    scene: str = ""

    @property
    def timestamp_ns(self) -> int:
        """The timestamp in integer nanoseconds, as MCAP stores it."""
        return round(self.timestamp * 1e9)

    def gray(self) -> np.ndarray:
        """The image as ``(H, W)`` uint8 luminance (OpenCV's ITU-R 601 weights)."""
        if self.image.ndim == 2:
            return self.image
        import cv2  # here, not at import: every plugin module imports this one

        return cv2.cvtColor(self.image, cv2.COLOR_RGB2GRAY)
