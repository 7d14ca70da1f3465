"""How a run logs each frame's own topics: its info, image, depth, cloud, calibration and pose.

The runtime asks the source for its frame logger (:meth:`slamfront.plugin.Source.frame_logger`)
and hands it every frame before the stages see it. :class:`FrameLogger` encodes the frame
as the recipe's ``log`` options say; a source whose frames arrive already encoded may pass
its own (a replayed log's source copies the original records unchanged).
"""

from __future__ import annotations

import functools

import numpy as np

from slamfront.frame import Frame
from slamfront.mcaplog import foxglove
from slamfront.mcaplog.topics import (
    CALIBRATION_TOPIC,
    DEPTH_TOPIC,
    FRAMES_TOPIC,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    POINTS_TOPIC,
    TF_TOPIC,
)
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import FrameInfo
from slamfront.recipe import LogOptions


class FrameLogger:
    """Writes what the source gave for a frame: its info, image, depth, cloud and pose."""

    def __init__(self, options: LogOptions) -> None:
        self.options = options

    def write(self, log: RunLogWriter, frame: Frame) -> FrameInfo:
        """Write ``frame``'s topics to ``log`` at the frame's time; return its ``FrameInfo``."""
        stamp = frame.timestamp_ns
        info = FrameInfo(
            frame=frame.index,
            timestamp=frame.timestamp,
            traversal=frame.traversal,
            sequence_index=frame.sequence_index,
            name=frame.name,
            width=int(frame.image.shape[1]),
            height=int(frame.image.shape[0]),
            has_depth=frame.depth is not None,
            pose=None if frame.pose is None else np.asarray(frame.pose, dtype=np.float64),
            scene=frame.scene,
        )
        options = self.options
        log.write(FRAMES_TOPIC, info, stamp)
        if options.images:  # compressed on the log's writing thread, beside the stages
            bgr = foxglove.image_to_encode(frame.image, options.image_max_width)
            encode = functools.partial(foxglove.encoded_image, bgr, stamp, options.image_format, options.jpeg_quality)
            log.write_foxglove_later(IMAGE_TOPIC, foxglove.CompressedImage, encode, stamp, bgr.nbytes // 8)
        if options.depth and frame.depth is not None:
            log.write_foxglove(DEPTH_TOPIC, foxglove.depth_image(frame.depth, stamp, options.depth_encoding), stamp)
        if options.points and frame.depth is not None and frame.camera is not None:
            points, colours = _cloud(frame, options.points_stride)
            log.write_foxglove(POINTS_TOPIC, foxglove.point_cloud(points, stamp, colours), stamp)
        if frame.camera is not None:
            log.write_foxglove(CALIBRATION_TOPIC, foxglove.camera_calibration(frame.camera, stamp), stamp)
        if frame.pose is not None:
            log.write_foxglove(GROUND_TRUTH_TOPIC, foxglove.pose_in_frame(frame.pose, stamp), stamp)
            log.write_foxglove(TF_TOPIC, foxglove.frame_transforms(frame.pose, stamp), stamp)
        return info


def _cloud(frame: Frame, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``stride``-th pixel with depth, back-projected into the camera frame."""
    assert frame.depth is not None and frame.camera is not None
    camera = frame.camera
    depth = frame.depth[::stride, ::stride]
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float32)
    u, v = u * stride, v * stride
    x = (u - camera.cx) / camera.fx * z
    y = (v - camera.cy) / camera.fy * z
    image = frame.image if frame.image.ndim == 3 else np.repeat(frame.image[..., None], 3, axis=2)
    return np.stack([x, y, z], axis=1).astype(np.float32), image[v, u]
