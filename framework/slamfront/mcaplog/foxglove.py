"""Build Foxglove protobuf messages from slamfront data, so logs open in Foxglove as-is.

Frames: ``map`` is the world frame of ground-truth and estimated poses; ``camera`` is
the camera of the current frame (x right, y down, z forward, as OpenCV).
"""

from __future__ import annotations

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

from slamfront.frame import Camera

MAP_FRAME = "map"
CAMERA_FRAME = "camera"


def timestamp(ns: int) -> Timestamp:
    stamp = Timestamp()
    stamp.FromNanoseconds(int(ns))
    return stamp


def _fill_pose(pose: Pose, matrix: np.ndarray) -> None:
    x, y, z = (float(v) for v in matrix[:3, 3])
    qx, qy, qz, qw = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    pose.position.x, pose.position.y, pose.position.z = x, y, z
    pose.orientation.x, pose.orientation.y = float(qx), float(qy)
    pose.orientation.z, pose.orientation.w = float(qz), float(qw)


def compressed_image(
    image: np.ndarray, stamp_ns: int, max_width: int, image_format: str, jpeg_quality: int
) -> CompressedImage:
    """An RGB or grey uint8 image, downscaled to ``max_width`` and encoded (jpeg/png)."""
    height, width = image.shape[:2]
    if width > max_width:
        scale = max_width / width
        image = cv2.resize(image, (max_width, max(1, round(height * scale))), interpolation=cv2.INTER_AREA)
    bgr = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if image_format == "jpeg" else []
    ok, encoded = cv2.imencode(f".{'jpg' if image_format == 'jpeg' else 'png'}", bgr, params)
    if not ok:
        raise ValueError("image encoding failed")
    return CompressedImage(
        timestamp=timestamp(stamp_ns), frame_id=CAMERA_FRAME, data=encoded.tobytes(), format=image_format
    )


def camera_calibration(camera: Camera, stamp_ns: int) -> CameraCalibration:
    """Pinhole intrinsics, so Foxglove can project the image in the 3-D panel."""
    k = camera.matrix
    p = np.hstack([k, np.zeros((3, 1))])
    return CameraCalibration(
        timestamp=timestamp(stamp_ns), frame_id=CAMERA_FRAME, width=camera.width, height=camera.height,
        distortion_model="plumb_bob", D=[0.0] * 5, K=k.ravel().tolist(), R=np.eye(3).ravel().tolist(),
        P=p.ravel().tolist(),
    )


def depth_image(depth_m: np.ndarray, stamp_ns: int) -> RawImage:
    """Depth in metres as a 16-bit millimetre ``RawImage`` (encoding ``16UC1``)."""
    millimetres = np.clip(np.nan_to_num(depth_m) * 1000.0, 0, 65535).astype("<u2")
    height, width = millimetres.shape
    return RawImage(
        timestamp=timestamp(stamp_ns),
        frame_id=CAMERA_FRAME,
        width=width,
        height=height,
        encoding="16UC1",
        step=width * 2,
        data=millimetres.tobytes(),
    )


def pose_in_frame(matrix: np.ndarray, stamp_ns: int, frame_id: str = MAP_FRAME) -> PoseInFrame:
    """A 4x4 camera-to-world transform as a ``PoseInFrame`` in ``frame_id``."""
    message = PoseInFrame(timestamp=timestamp(stamp_ns), frame_id=frame_id)
    _fill_pose(message.pose, matrix)
    return message


def poses_in_frame(matrices: np.ndarray, stamp_ns: int, frame_id: str = MAP_FRAME) -> PosesInFrame:
    """(N, 4, 4) transforms as one ``PosesInFrame`` (a trajectory)."""
    message = PosesInFrame(timestamp=timestamp(stamp_ns), frame_id=frame_id)
    for matrix in matrices:
        _fill_pose(message.poses.add(), matrix)
    return message


def frame_transforms(matrix: np.ndarray, stamp_ns: int, parent: str = MAP_FRAME, child: str = CAMERA_FRAME) -> FrameTransforms:
    """The transform placing ``child`` in ``parent`` (so the 3-D panel can follow the camera)."""
    transform = FrameTransform(timestamp=timestamp(stamp_ns), parent_frame_id=parent, child_frame_id=child)
    x, y, z = (float(v) for v in matrix[:3, 3])
    qx, qy, qz, qw = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    transform.translation.x, transform.translation.y, transform.translation.z = x, y, z
    transform.rotation.x, transform.rotation.y = float(qx), float(qy)
    transform.rotation.z, transform.rotation.w = float(qz), float(qw)
    return FrameTransforms(transforms=[transform])


def scene_lines(
    segments: np.ndarray,
    stamp_ns: int,
    entity_id: str,
    color: tuple[float, float, float, float] = (0.9, 0.1, 0.1, 1.0),
    thickness_px: float = 2.0,
    frame_id: str = MAP_FRAME,
) -> SceneUpdate:
    """Line segments as one ``SceneUpdate`` entity (a LINE_LIST), e.g. loop-closure edges.

    :param segments: (K, 2, 3) or (K, 2, 2) segment endpoints (planar ones at z = 0).
    :param entity_id: the entity to replace: a later update with the same id redraws it.
    """
    segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, np.shape(segments)[-1] if len(segments) else 3)
    if segments.shape[-1] == 2:
        segments = np.concatenate([segments, np.zeros((*segments.shape[:2], 1))], axis=-1)
    update = SceneUpdate()
    entity = update.entities.add(timestamp=timestamp(stamp_ns), frame_id=frame_id, id=entity_id)
    entity.frame_locked = True
    line = entity.lines.add(
        type=LinePrimitive.LINE_LIST, thickness=thickness_px, scale_invariant=True,
        color=Color(r=color[0], g=color[1], b=color[2], a=color[3]),
    )
    line.pose.orientation.w = 1.0
    for x, y, z in segments.reshape(-1, 3).tolist():
        line.points.add(x=x, y=y, z=z)
    return update


_LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR, "fatal": Log.FATAL}


def log_line(text: str, stamp_ns: int, level: str = "info", name: str = "slamfront") -> Log:
    """A human-readable event for Foxglove's Log panel."""
    return Log(timestamp=timestamp(stamp_ns), level=_LEVELS[level], message=text, name=name)
