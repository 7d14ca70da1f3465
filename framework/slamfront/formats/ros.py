"""ROS messages as arrays: images, depth, intrinsics, poses and transforms.

The functions take messages as the ``rosbags`` library deserialises them (plain objects
whose fields are named as in the ``.msg`` definitions: ROS 1's ``CameraInfo.K`` and ROS 2's
``CameraInfo.k`` are both understood) and return what a :class:`~slamfront.frame.Frame`
holds: uint8 RGB or grey pixels, float32 depth in metres, a pinhole
:class:`~slamfront.frame.Camera`, (4, 4) transforms. Nothing here reads a file; a bad
message raises :class:`~slamfront.errors.DataError` naming ``what`` (bag, topic, message).

Encodings follow ``sensor_msgs/image_encodings.h``: ``rgb8``, ``bgr8``, ``rgba8``,
``bgra8``, ``mono8``, ``mono16``, ``8UC1``, ``8UC3`` (BGR, as OpenCV writes it),
``bayer_{rggb,bggr,gbrg,grbg}{8,16}`` for colour; ``16UC1``/``mono16`` (millimetres) and
``32FC1`` (metres) for depth. ``CompressedImage`` holds JPEG/PNG bytes; depth compressed
by ``compressed_depth_image_transport`` (format ``"16UC1; compressedDepth png"`` or
``"32FC1; compressedDepth png"``) is a 12-byte header then a PNG.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from slamfront.errors import DataError
from slamfront.frame import Camera
from slamfront.imageio import decode_image
from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

COLOUR_ENCODINGS = (
    "rgb8", "bgr8", "rgba8", "bgra8", "mono8", "mono16", "8UC1", "8UC3",
    "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8",
    "bayer_rggb16", "bayer_bggr16", "bayer_gbrg16", "bayer_grbg16",
)
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")

# OpenCV names a Bayer pattern by the second row's first two pixels (its documented quirk):
# ROS's rggb (R G / G B) is OpenCV's BayerBG
# (the conversion codes' names, looked up when a Bayer image is decoded: cv2 loads lazily)
_BAYER = {
    "rggb": "COLOR_BayerBG2RGB", "bggr": "COLOR_BayerRG2RGB",
    "gbrg": "COLOR_BayerGR2RGB", "grbg": "COLOR_BayerGB2RGB",
}
_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8UC1": 1, "8UC3": 3}


def stamp_ns(message: Any) -> int:
    """A stamped message's ``header.stamp`` in integer nanoseconds."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _pixels(message: Any, dtype: np.dtype, channels: int, what: str) -> np.ndarray:
    """The ``(H, W[, C])`` array a raw ``sensor_msgs/Image`` holds (row padding removed)."""
    height, width, step = int(message.height), int(message.width), int(message.step)
    itemsize = np.dtype(dtype).itemsize
    data = np.asarray(message.data, dtype=np.uint8).reshape(-1)
    if height <= 0 or width <= 0:
        raise DataError(f"{what}: empty image ({width}x{height})")
    if step < width * channels * itemsize or len(data) < step * (height - 1) + width * channels * itemsize:
        raise DataError(
            f"{what}: {len(data)} data bytes and step {step} do not hold a {width}x{height} {message.encoding} image"
        )
    row = width * channels * itemsize
    if step == row:  # no padding: a view of the message's bytes, no copy
        rows = data[: height * row].reshape(height, row)
    else:
        rows = np.ascontiguousarray(np.lib.stride_tricks.as_strided(data, (height, row), (step, 1)))
    order = ">" if bool(message.is_bigendian) else "<"
    array = rows.view(np.dtype(dtype).newbyteorder(order) if itemsize > 1 else dtype)
    array = array.astype(dtype, copy=False)  # big-endian words: to this machine's order
    return array.reshape(height, width, channels) if channels > 1 else array.reshape(height, width)


def image_from_ros(message: Any, what: str) -> np.ndarray:
    """A ``sensor_msgs/Image`` as uint8 RGB ``(H, W, 3)`` or grey ``(H, W)``.

    16-bit grey and Bayer images are scaled to 8 bits.

    :raises DataError: an encoding not in :data:`COLOUR_ENCODINGS`, or sizes that disagree.
    """
    encoding = str(message.encoding)
    if encoding in _CHANNELS:
        pixels = _pixels(message, np.uint8, _CHANNELS[encoding], what)
        if encoding in ("rgb8",) or pixels.ndim == 2:
            return pixels  # a read-only view of the message's bytes (frames are never changed in place)
        if encoding == "rgba8":
            return np.ascontiguousarray(pixels[..., :3])
        if encoding == "bgra8":
            return cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGB)
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)  # bgr8, 8UC3
    if encoding == "mono16":
        return (_pixels(message, np.uint16, 1, what) >> 8).astype(np.uint8)
    if encoding.startswith("bayer_") and encoding[6:10] in _BAYER and encoding[10:] in ("8", "16"):
        raw = _pixels(message, np.uint8 if encoding.endswith("8") else np.uint16, 1, what)
        if raw.dtype == np.uint16:
            raw = (raw >> 8).astype(np.uint8)
        return cv2.cvtColor(raw, getattr(cv2, _BAYER[encoding[6:10]]))
    raise DataError(f"{what}: unsupported image encoding {encoding!r} (supported: {', '.join(COLOUR_ENCODINGS)})")


def compressed_image_from_ros(message: Any, what: str) -> np.ndarray:
    """A ``sensor_msgs/CompressedImage`` (JPEG, PNG, ...) as uint8 RGB ``(H, W, 3)``.

    :raises DataError: undecodable bytes, or compressed depth on a colour topic.
    """
    form = str(message.format).lower()
    if "compresseddepth" in form:
        raise DataError(f"{what}: format {message.format!r} is compressed depth, not a colour image")
    return decode_image(bytes(message.data), what, "rgb")


def depth_from_ros(message: Any, what: str, millimetres_per_metre: float = 1000.0) -> np.ndarray:
    """A depth ``sensor_msgs/Image`` as float32 metres, 0 where there is no return.

    :param millimetres_per_metre: raw units per metre of 16-bit depth (1000: millimetres).
    :raises DataError: an encoding not in :data:`DEPTH_ENCODINGS`.
    """
    encoding = str(message.encoding)
    if encoding in ("16UC1", "mono16"):  # one pass: integers to float32 metres
        return np.divide(_pixels(message, np.uint16, 1, what), np.float32(millimetres_per_metre), dtype=np.float32)
    if encoding == "32FC1":
        depth = _pixels(message, np.float32, 1, what)
        return np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0)).astype(np.float32)
    raise DataError(f"{what}: unsupported depth encoding {encoding!r} (supported: {', '.join(DEPTH_ENCODINGS)})")


def compressed_depth_from_ros(message: Any, what: str, millimetres_per_metre: float = 1000.0) -> np.ndarray:
    """Depth from ``compressed_depth_image_transport`` (``"<encoding>; compressedDepth png"``)
    as float32 metres: 16UC1 is millimetres in a 16-bit PNG; 32FC1 is inverse depth
    quantised as ``depth = a / (value - b)`` with ``a, b`` from the 12-byte header.

    :raises DataError: another format (``rvl``, JPEG depth), or undecodable bytes.
    """
    form = str(message.format)
    encoding, _, rest = form.partition(";")
    encoding, rest = encoding.strip(), rest.strip().lower()
    if "compresseddepth" not in rest or (rest.split()[-1:] != ["png"] and rest != "compresseddepth"):
        raise DataError(f"{what}: unsupported compressed depth format {form!r} (supported: compressedDepth png)")
    data = bytes(message.data)
    if len(data) <= 12:
        raise DataError(f"{what}: compressed depth of {len(data)} bytes holds no image")
    quant_a, quant_b = np.frombuffer(data[4:12], dtype="<f4")
    raw = decode_image(data[12:], what, "unchanged")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise DataError(f"{what}: compressed depth must be a one-channel 16-bit PNG, got {raw.dtype} {raw.shape}")
    if encoding in ("16UC1", "mono16"):
        return raw.astype(np.float32) / np.float32(millimetres_per_metre)
    if encoding == "32FC1":
        values = raw.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.float32(quant_a) / (values - np.float32(quant_b))
        return np.where((raw > 0) & np.isfinite(depth) & (depth > 0), depth, np.float32(0)).astype(np.float32)
    raise DataError(f"{what}: unsupported compressed depth encoding {encoding!r} (supported: 16UC1, 32FC1)")


def camera_from_ros(message: Any, what: str) -> tuple[Camera, str, np.ndarray]:
    """Intrinsics from a ``sensor_msgs/CameraInfo``: the pinhole camera (from ``K``), the
    distortion model name and its coefficients ``D`` (possibly empty).

    :raises DataError: a zero focal length (an uncalibrated camera publishes all zeros).
    """
    k = np.asarray(getattr(message, "k", None) if hasattr(message, "k") else message.K, dtype=np.float64)
    d = np.asarray(getattr(message, "d", None) if hasattr(message, "d") else message.D, dtype=np.float64)
    model = str(getattr(message, "distortion_model", "") or "")
    if k.shape != (9,) or k[0] <= 0 or k[4] <= 0:
        raise DataError(f"{what}: CameraInfo has no calibration (K = {k.tolist()}); give the source a `camera`")
    camera = Camera(fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]),
                    width=int(message.width), height=int(message.height))
    return camera, model, d


def _pose(position: Any, orientation: Any, what: str) -> np.ndarray:
    """(4, 4) from a position and a quaternion (normalised): the formula of
    :func:`~slamfront.core.geometry.quaternion_matrices` on plain floats, without array
    overhead (poses come at hundreds of Hz); equal to it within 1e-15."""
    x, y, z, w = (float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w))
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(norm) or norm < 1e-12:
        raise DataError(f"{what}: invalid quaternion {[x, y, z, w]}")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array([
        [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw), float(position.x)],
        [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw), float(position.y)],
        [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2, float(position.z)],
        [0.0, 0.0, 0.0, 1.0],
    ])


def transform_from_ros(transform: Any, what: str) -> np.ndarray:
    """A ``geometry_msgs/Transform`` (translation + rotation) as a (4, 4) matrix."""
    return _pose(transform.translation, transform.rotation, what)


POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/TransformStamped",
)
"""Message types a ground-truth pose topic may carry (ROS 2 names; ROS 1's are the same
without ``/msg/``)."""


def pose_from_ros(message: Any, msgtype: str, what: str) -> np.ndarray:
    """The (4, 4) pose a ``PoseStamped``, ``PoseWithCovarianceStamped``, ``Odometry`` or
    ``TransformStamped`` holds (of its child/body frame in its header's frame).

    :raises DataError: another message type.
    """
    kind = msgtype.replace("/msg/", "/")
    if kind == "geometry_msgs/PoseStamped":
        return _pose(message.pose.position, message.pose.orientation, what)
    if kind in ("geometry_msgs/PoseWithCovarianceStamped", "nav_msgs/Odometry"):
        return _pose(message.pose.pose.position, message.pose.pose.orientation, what)
    if kind == "geometry_msgs/TransformStamped":
        return transform_from_ros(message.transform, what)
    raise DataError(f"{what}: a pose topic must carry one of {', '.join(POSE_TYPES)}; this one carries {msgtype}")


class TransformTree:
    """A ``/tf`` tree over time: static transforms forever, dynamic ones for a window.

    Transforms are kept per child frame as ``T_parent_child`` (the child's pose in its
    parent, ROS's convention for ``TransformStamped``). :meth:`lookup` chains them from
    one frame to another at a time, taking each dynamic edge nearest that time.
    """

    def __init__(self) -> None:
        self._static: dict[str, tuple[str, np.ndarray]] = {}
        self._dynamic: dict[str, tuple[str, list[int], list[np.ndarray]]] = {}

    def add(self, parent: str, child: str, stamp: int, transform: np.ndarray, static: bool = False) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if static:
            self._static[child] = (parent, transform)
            return
        known = self._dynamic.get(child)
        if known is None or known[0] != parent:  # a re-parented frame starts a new history
            known = (parent, [], [])
            self._dynamic[child] = known
        _, stamps, transforms = known
        at = int(np.searchsorted(stamps, stamp, side="right"))
        stamps.insert(at, stamp)
        transforms.insert(at, transform)

    def forget_before(self, stamp: int) -> None:
        """Drop dynamic transforms older than ``stamp`` (keeping each edge's last such one)."""
        for _, stamps, transforms in self._dynamic.values():
            cut = max(int(np.searchsorted(stamps, stamp, side="left")) - 1, 0)
            del stamps[:cut], transforms[:cut]

    def _edge(self, child: str, stamp: int, tolerance: int) -> tuple[str, np.ndarray] | None:
        if child in self._static:
            return self._static[child]
        known = self._dynamic.get(child)
        if known is None or not known[1]:
            return None
        parent, stamps, transforms = known
        at = int(np.searchsorted(stamps, stamp))
        best = min((i for i in (at - 1, at) if 0 <= i < len(stamps)), key=lambda i: abs(stamps[i] - stamp))
        return (parent, transforms[best]) if abs(stamps[best] - stamp) <= tolerance else None

    def _to_ancestors(self, frame: str, stamp: int, tolerance: int) -> dict[str, np.ndarray]:
        """Every ancestor of ``frame`` reachable at ``stamp`` -> ``frame``'s pose in it."""
        chain = {frame: np.eye(4)}
        current, pose = frame, np.eye(4)
        for _ in range(256):  # a cycle in a broken tree must not hang the run
            edge = self._edge(current, stamp, tolerance)
            if edge is None:
                break
            current, pose = edge[0], edge[1] @ pose
            if current in chain:
                break
            chain[current] = pose
        return chain

    def lookup(self, target: str, source: str, stamp: int, tolerance: int) -> np.ndarray | None:
        """``source``'s pose in ``target`` at ``stamp`` (``T_target_source``), or None when
        the tree does not connect them with transforms within ``tolerance`` of ``stamp``."""
        target, source = target.lstrip("/"), source.lstrip("/")
        up_from_source = self._to_ancestors(source, stamp, tolerance)
        for ancestor, target_in_ancestor in self._to_ancestors(target, stamp, tolerance).items():
            if ancestor in up_from_source:
                return np.linalg.inv(target_in_ancestor) @ up_from_source[ancestor]
        return None

    def frames(self) -> list[str]:
        """Every frame the tree has seen, for messages."""
        names = set(self._static) | set(self._dynamic)
        names |= {parent for parent, _ in self._static.values()} | {known[0] for known in self._dynamic.values()}
        return sorted(names)
