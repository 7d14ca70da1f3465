"""The global model: aligned clouds concatenated and kept on a voxel grid."""

from __future__ import annotations

import numpy as np

from slamfront.core.clouds import transform_points
from slamfront.lazy import lazy_module

o3d = lazy_module("open3d")  # loads on first use: listing plugins does not import it


def voxelise(points: np.ndarray, colors: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel (the centroid, with the mean colour)."""
    if len(points) == 0:
        return np.empty((0, 3), np.float32), np.empty((0, 3), np.uint8)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(colors.astype(np.float64) / 255.0)
    down = cloud.voxel_down_sample(voxel)
    return (
        np.asarray(down.points, dtype=np.float32),
        np.round(np.asarray(down.colors) * 255.0).astype(np.uint8),
    )


class ModelBuilder:
    """Accumulates aligned clouds into one model.

    With ``keep_parts`` (a pose graph may still move the clouds) each cloud is kept in
    its camera frame and placed at :meth:`build`. Without it, clouds are placed in the
    world as they come and the model is re-voxelised whenever it doubles, so memory
    follows the size of the scene, not the number of frames.
    """

    def __init__(self, voxel: float, keep_parts: bool) -> None:
        self.voxel = voxel
        self.keep_parts = keep_parts
        self._parts: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._size = 0
        self._compacted = 0

    def add(self, frame: int, points: np.ndarray, colors: np.ndarray, pose: np.ndarray) -> None:
        """Add a cloud given in the camera frame of ``frame`` at camera-to-world ``pose``."""
        if not self.keep_parts:
            points = transform_points(pose, points)
        self._parts.append((frame, points, colors))
        self._size += len(points)
        if not self.keep_parts and self._size > 2 * max(self._compacted, 100_000):
            self._parts = [(frame, *self._merge(self._parts))]
            self._size = self._compacted = len(self._parts[0][1])

    def build(self, poses: dict[int, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The model: ``(N, 3)`` float32 world points and ``(N, 3)`` uint8 colours.

        :param poses: final camera-to-world poses by frame (needed with ``keep_parts``).
        """
        parts = self._parts
        if self.keep_parts:
            if poses is None:
                raise ValueError("a model that keeps its parts needs the final poses")
            parts = [(frame, transform_points(poses[frame], points), colors) for frame, points, colors in parts]
        return self._merge(parts)

    def _merge(self, parts: list[tuple[int, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        if not parts:
            return voxelise(np.empty((0, 3)), np.empty((0, 3)), self.voxel)
        return voxelise(np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts]), self.voxel)
