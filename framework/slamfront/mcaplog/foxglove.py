"""Build Foxglove protobuf messages from slamfront data, so logs open in Foxglove as-is.

Frames: ``map`` is the world frame of ground-truth and estimated poses; ``camera`` is
the camera of the current frame (x right, y down, z forward, as OpenCV).
"""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

from slamfront import imageio
from slamfront.errors import DataError
from slamfront.frame import Camera
from slamfront.lazy import lazy_module
from slamfront.limits import over_limit

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

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
    return encoded_image(image_to_encode(image, max_width), stamp_ns, image_format, jpeg_quality)


def image_to_encode(image: np.ndarray, max_width: int) -> np.ndarray:
    """What :func:`encoded_image` compresses: ``image`` downscaled to ``max_width``, in
    OpenCV's BGR order, always a new array (it may be encoded later, on another thread)."""
    height, width = image.shape[:2]
    if width > max_width:
        scale = max_width / width
        image = cv2.resize(image, (max_width, max(1, round(height * scale))), interpolation=cv2.INTER_AREA)
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    return image.copy() if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)


def encoded_image(bgr: np.ndarray, stamp_ns: int, image_format: str, jpeg_quality: int) -> CompressedImage:
    """:func:`image_to_encode`'s output compressed (jpeg/png) into a Foxglove message."""
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


DEPTH_ENCODINGS = ("16UC1", "32FC1")


def depth_image(depth_m: np.ndarray, stamp_ns: int, encoding: str = "16UC1") -> RawImage:
    """Depth as a ``RawImage``: ``16UC1`` millimetres (compact), or ``32FC1`` metres
    (the float32 values bit for bit, so a replay can feed them to a stage again)."""
    if encoding == "16UC1":
        pixels = np.clip(np.nan_to_num(depth_m) * 1000.0, 0, 65535).astype("<u2")
    elif encoding == "32FC1":
        pixels = np.asarray(depth_m, dtype="<f4")
    else:
        raise ValueError(f"depth encoding must be one of {DEPTH_ENCODINGS}, not {encoding!r}")
    height, width = pixels.shape
    return RawImage(
        timestamp=timestamp(stamp_ns),
        frame_id=CAMERA_FRAME,
        width=width,
        height=height,
        encoding=encoding,
        step=width * pixels.itemsize,
        data=pixels.tobytes(),
    )


def decode_depth(message: RawImage, what: str = "a logged depth image") -> np.ndarray:
    """(H, W) float32 metres from :func:`depth_image`'s output.

    :raises DataError: the data does not hold the declared width x height (or exceeds the pixel limit).
    """
    dtype = np.dtype("<u2" if message.encoding == "16UC1" else "<f4")
    size = f"{message.width}x{message.height}"
    problem = over_limit("image_pixels", message.width * message.height, f"the pixel count of the {size} image it declares")
    if problem:
        raise DataError(f"{what}: {problem}")
    if len(message.data) != message.width * message.height * dtype.itemsize:
        raise DataError(
            f"{what}: holds {len(message.data)} bytes, not the {message.width}x{message.height} {message.encoding} "
            "pixels it declares"
        )
    pixels = np.frombuffer(message.data, dtype=dtype).reshape(message.height, message.width)
    return pixels.astype(np.float32) / 1000.0 if message.encoding == "16UC1" else pixels.astype(np.float32)


def decode_image(message: CompressedImage, what: str = "a logged image") -> np.ndarray:
    """The RGB (or grey) uint8 image of :func:`compressed_image`'s output.

    :raises DataError: undecodable, or over the pixel limit (naming ``what``).
    """
    return imageio.decode_image(message.data, what, "unchanged")


def point_cloud(
    points: np.ndarray, stamp_ns: int, colors: np.ndarray | None = None, frame_id: str = CAMERA_FRAME
) -> PointCloud:
    """(N, 3) points (float32 x, y, z) with optional (N, 3) uint8 RGB colours."""
    points = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    fields = [
        PackedElementField(name=axis, offset=4 * k, type=PackedElementField.FLOAT32) for k, axis in enumerate("xyz")
    ]
    if colors is None:
        record = points
    else:
        rgba = np.concatenate(
            [np.asarray(colors, dtype=np.uint8).reshape(-1, 3), np.full((len(points), 1), 255, np.uint8)], axis=1
        )
        record = np.empty(len(points), dtype=[("xyz", "<f4", 3), ("rgba", "u1", 4)])
        record["xyz"], record["rgba"] = points, rgba
        fields += [
            PackedElementField(name=name, offset=12 + k, type=PackedElementField.UINT8)
            for k, name in enumerate(("red", "green", "blue", "alpha"))
        ]
    message = PointCloud(
        timestamp=timestamp(stamp_ns),
        frame_id=frame_id,
        point_stride=int(record.itemsize if colors is not None else 12),
        fields=fields,
        data=record.tobytes(),
    )
    message.pose.orientation.w = 1.0  # the identity: the points are already in frame_id
    return message


def line_entity(
    entity_id: str,
    points: np.ndarray,
    stamp_ns: int,
    rgba: tuple[float, float, float, float],
    strip: bool,
    thickness: float = 2.0,
    frame_id: str = MAP_FRAME,
) -> SceneEntity:
    """A scene entity of lines: a polyline through (N, 3) ``points`` when ``strip``, else
    segments between consecutive pairs. Thickness in pixels (scale invariant)."""
    entity = SceneEntity(timestamp=timestamp(stamp_ns), frame_id=frame_id, id=entity_id)
    line = entity.lines.add()
    line.type = LinePrimitive.LINE_STRIP if strip else LinePrimitive.LINE_LIST
    line.thickness = thickness
    line.scale_invariant = True
    line.pose.orientation.w = 1.0
    line.color.CopyFrom(Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))
    for x, y, z in np.asarray(points, dtype=np.float64).reshape(-1, 3):
        point = line.points.add()
        point.x, point.y, point.z = float(x), float(y), float(z)
    return entity


def scene_update(entities: list[SceneEntity]) -> SceneUpdate:
    """A ``SceneUpdate`` replacing the given entities (same id: the newer one wins)."""
    return SceneUpdate(entities=entities)


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


_LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR, "fatal": Log.FATAL}


def log_line(
    text: str, stamp_ns: int, level: str = "info", name: str = "slamfront", file: str = "", line: int = 0
) -> Log:
    """A human-readable event for Foxglove's Log panel (``file``, ``line``: where it was logged)."""
    return Log(timestamp=timestamp(stamp_ns), level=_LEVELS[level], message=text, name=name, file=file, line=line)
