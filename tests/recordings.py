"""Writing frames as robots record them: ROS 1 / ROS 2 bags, EuRoC, KITTI odometry and video.

The tests (and the recordings benchmark) turn synthetic-world frames into the layouts the
recording sources read, so every source is exercised on files that mirror the real ones
without any real data. Bags are written with ``rosbags``, the library the ``ros_bag``
source reads them with, using its ROS 1 Noetic / ROS 2 Humble message definitions.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from slamfront.core.geometry import quaternion_of
from slamfront.frame import Frame

ImageEncoding = Literal["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "mono16", "bayer_rggb8", "jpeg", "png"]
DepthEncoding = Literal["16UC1", "32FC1", "compressedDepth", "compressedDepth32"]
PoseKind = Literal["PoseStamped", "PoseWithCovarianceStamped", "Odometry", "TransformStamped", "tf"]

TOPICS = {
    "image": "/camera/color/image_raw", "depth": "/camera/aligned_depth_to_color/image_raw",
    "info": "/camera/color/camera_info", "pose": "/ground_truth/pose",
}


@dataclass
class BagSpec:
    """What a test bag holds and how it encodes it."""

    ros: Literal[1, 2] = 2
    storage: Literal["mcap", "sqlite3"] = "mcap"
    image: ImageEncoding = "rgb8"
    depth: DepthEncoding | None = "16UC1"
    pose: PoseKind | None = "PoseStamped"
    camera_info: bool = True
    jpeg_quality: int = 80
    distortion: tuple[float, ...] = ()
    stamp_offset_s: float = 0.0
    """Added to every frame's timestamp (a bag's clock is the robot's)."""
    topics: dict[str, str] = field(default_factory=lambda: dict(TOPICS))
    """Topic names (``image`` and ``depth`` before the image_transport suffix)."""

    @property
    def image_topic(self) -> str:
        return self.topics["image"] + ("/compressed" if self.image in ("jpeg", "png") else "")

    @property
    def depth_topic(self) -> str:
        return self.topics["depth"] + ("/compressedDepth" if self.depth and self.depth.startswith("compressed") else "")

    def source_params(self, path: Path) -> dict[str, Any]:
        """The ``ros_bag`` params that read this bag."""
        params: dict[str, Any] = {"path": str(path), "image_topic": self.image_topic}
        if self.depth:
            params["depth_topic"] = self.depth_topic
        if self.camera_info:
            params["camera_info_topic"] = self.topics["info"]
        if self.pose == "tf":
            params.update(tf_parent_frame="map", tf_child_frame="camera_optical")
        elif self.pose:
            params["pose_topic"] = self.topics["pose"]
        return params


class BagWriter:
    """Writes frames into a bag as :class:`BagSpec` says; a context manager."""

    def __init__(self, path: Path, spec: BagSpec) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.spec = spec
        self.store = get_typestore(Stores.ROS1_NOETIC if spec.ros == 1 else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.store.types:  # not in rosbags' Noetic store
            from rosbags.typesys import get_types_from_msg

            self.store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
        self.types = self.store.types
        if spec.ros == 1:
            from rosbags.rosbag1 import Writer as Writer1

            self.writer: Any = Writer1(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if spec.storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(self.path, version=9, storage_plugin=plugin)
        self.connections: dict[str, Any] = {}
        self.seq = 0

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def _write(self, topic: str, msgtype: str, message: Any, stamp_ns: int) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        data = (self.store.serialize_ros1 if self.spec.ros == 1 else self.store.serialize_cdr)(message, msgtype)
        self.writer.write(self.connections[topic], stamp_ns, data)

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        time = self.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        if self.spec.ros == 1:
            self.seq += 1
            return self.types["std_msgs/msg/Header"](seq=self.seq, stamp=time, frame_id=frame_id)
        return self.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def raw_image(self, stamp_ns: int, pixels: np.ndarray, encoding: str, frame_id: str = "camera_optical") -> Any:
        height, width = pixels.shape[:2]
        data = np.ascontiguousarray(pixels)
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(stamp_ns, frame_id), height=height, width=width, encoding=encoding, is_bigendian=0,
            step=data.nbytes // height, data=data.view(np.uint8).reshape(-1),
        )

    def compressed(self, stamp_ns: int, data: bytes, form: str) -> Any:
        return self.types["sensor_msgs/msg/CompressedImage"](
            header=self.header(stamp_ns, "camera_optical"), format=form, data=np.frombuffer(data, np.uint8).copy()
        )

    def write_frame(self, frame: Frame) -> None:
        spec = self.spec
        stamp = round((frame.timestamp + spec.stamp_offset_s) * 1e9)
        msg_image = self._image(stamp, frame.image)
        self._write(spec.image_topic, msg_image.__msgtype__, msg_image, stamp)
        if spec.depth and frame.depth is not None:
            msg_depth = self._depth(stamp, frame.depth)
            self._write(spec.depth_topic, msg_depth.__msgtype__, msg_depth, stamp)
        if spec.camera_info and frame.camera is not None:
            self._write(spec.topics["info"], "sensor_msgs/msg/CameraInfo", self._info(stamp, frame), stamp)
        if spec.pose and frame.pose is not None:
            self._pose(stamp, frame.pose)

    def _image(self, stamp: int, rgb: np.ndarray) -> Any:
        kind = self.spec.image
        if kind == "jpeg":
            ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                    [cv2.IMWRITE_JPEG_QUALITY, self.spec.jpeg_quality])
            return self.compressed(stamp, data.tobytes(), "rgb8; jpeg compressed bgr8")
        if kind == "png":
            ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            return self.compressed(stamp, data.tobytes(), "rgb8; png compressed bgr8")
        converted = {
            "rgb8": lambda: rgb, "bgr8": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
            "rgba8": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2RGBA), "bgra8": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2BGRA),
            "mono8": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY),
            "mono16": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.uint16) * 257,
            "bayer_rggb8": lambda: bayer_rggb(rgb),
        }[kind]()
        return self.raw_image(stamp, converted, kind)

    def _depth(self, stamp: int, depth: np.ndarray) -> Any:
        kind = self.spec.depth
        millimetres = np.clip(np.round(depth * 1000.0), 0, 65535).astype(np.uint16)
        if kind == "16UC1":
            return self.raw_image(stamp, millimetres, "16UC1")
        if kind == "32FC1":
            metres = np.where(depth > 0, depth, np.nan).astype(np.float32)  # drivers give NaN where no return
            return self.raw_image(stamp, metres, "32FC1")
        if kind == "compressedDepth":
            ok, png = cv2.imencode(".png", millimetres)
            return self.compressed(stamp, struct.pack("<iff", 0, 0.0, 0.0) + png.tobytes(), "16UC1; compressedDepth png")
        # 32FC1 compressedDepth: inverse depth, quantised as compressed_depth_image_transport does
        # (depth_quantization 100, depth_max 50 m): value = a / depth + b
        a = 100.0 * (100.0 + 1.0)
        b = 1.0 - a / 50.0
        quantised = np.where(depth > 0, a / np.maximum(depth, 1e-6) + b, 0).clip(0, 65535).astype(np.uint16)
        ok, png = cv2.imencode(".png", quantised)
        return self.compressed(stamp, struct.pack("<iff", 0, a, b) + png.tobytes(), "32FC1; compressedDepth png")

    def _info(self, stamp: int, frame: Frame) -> Any:
        camera = frame.camera
        assert camera is not None
        k = np.array([camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1], dtype=np.float64)
        p = np.array([camera.fx, 0, camera.cx, 0, 0, camera.fy, camera.cy, 0, 0, 0, 1, 0], dtype=np.float64)
        d = np.array(self.spec.distortion or [0.0] * 5, dtype=np.float64)
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                              do_rectify=False)
        fields = {"d": d, "k": k, "r": np.eye(3).reshape(-1), "p": p}
        if self.spec.ros == 1:
            fields = {key.upper(): value for key, value in fields.items()}
        return self.types["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp, "camera_optical"), height=camera.height, width=camera.width,
            distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **fields,
        )

    def _geometry(self, pose: np.ndarray) -> tuple[Any, Any]:
        t = self.types
        q = quaternion_of(pose)
        point = t["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3]))
        quat = t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
        return point, quat

    def _pose(self, stamp: int, pose: np.ndarray) -> None:
        t = self.types
        kind = self.spec.pose
        point, quat = self._geometry(pose)
        plain = t["geometry_msgs/msg/Pose"](position=point, orientation=quat)
        covariance = np.zeros(36, dtype=np.float64)
        if kind == "PoseStamped":
            message = t["geometry_msgs/msg/PoseStamped"](header=self.header(stamp, "map"), pose=plain)
        elif kind == "PoseWithCovarianceStamped":
            with_cov = t["geometry_msgs/msg/PoseWithCovariance"](pose=plain, covariance=covariance)
            message = t["geometry_msgs/msg/PoseWithCovarianceStamped"](header=self.header(stamp, "map"), pose=with_cov)
        elif kind == "Odometry":
            with_cov = t["geometry_msgs/msg/PoseWithCovariance"](pose=plain, covariance=covariance)
            zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            twist = t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=covariance)
            message = t["nav_msgs/msg/Odometry"](header=self.header(stamp, "odom"), child_frame_id="camera_optical",
                                                 pose=with_cov, twist=twist)
        elif kind == "TransformStamped":
            message = self._transform(stamp, "map", "camera_optical", pose)
        else:
            self._tf(stamp, pose)
            return
        self._write(self.spec.topics["pose"], message.__msgtype__, message, stamp)

    def _transform(self, stamp: int, parent: str, child: str, pose: np.ndarray) -> Any:
        t = self.types
        point, quat = self._geometry(pose)
        translation = t["geometry_msgs/msg/Vector3"](x=point.x, y=point.y, z=point.z)
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](translation=translation, rotation=quat),
        )

    def _tf(self, stamp: int, pose: np.ndarray) -> None:
        """The camera's pose as a chain map -> odom -> base_link (dynamic) -> camera_optical (static)."""
        t = self.types
        if not self.connections.get("/tf_static"):
            mount = np.eye(4)
            mount[:3, 3] = [0.1, 0.0, 0.2]
            self._mount = mount
            static = t["tf2_msgs/msg/TFMessage"](transforms=[
                self._transform(stamp, "base_link", "camera_optical", mount),
                self._transform(stamp, "map", "odom", np.eye(4)),
            ])
            self._write("/tf_static", "tf2_msgs/msg/TFMessage", static, stamp)
        base = pose @ np.linalg.inv(self._mount)
        dynamic = t["tf2_msgs/msg/TFMessage"](transforms=[self._transform(stamp, "odom", "base_link", base)])
        self._write("/tf", "tf2_msgs/msg/TFMessage", dynamic, stamp)


def bayer_rggb(rgb: np.ndarray) -> np.ndarray:
    """An RGGB Bayer mosaic of an RGB image (R G / G B in each 2x2 cell)."""
    mosaic = np.empty(rgb.shape[:2], dtype=np.uint8)
    mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]
    mosaic[0::2, 1::2] = rgb[0::2, 1::2, 1]
    mosaic[1::2, 0::2] = rgb[1::2, 0::2, 1]
    mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return mosaic


def write_bag(path: Path, frames: Iterable[Frame], spec: BagSpec) -> Path:
    """Every frame into a new bag at ``path`` (a .bag file, or a rosbag2 folder)."""
    with BagWriter(path, spec) as writer:
        for frame in frames:
            writer.write_frame(frame)
    return path


# --- EuRoC (ASL), KITTI odometry, video --------------------------------------------------

EUROC_BODY_TO_CAMERA = np.array(
    [[0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
     [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
     [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
     [0.0, 0.0, 0.0, 1.0]]
)
"""EuRoC's cam0 T_BS (the camera in the body frame), as its sensor.yaml gives it."""


def write_euroc(root: Path, frames: Iterable[Frame], distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0),
                truth_per_frame: int = 4, epoch_ns: int = 1_403_636_579_763_555_584) -> Path:
    """A EuRoC ASL sequence: ``mav0/cam0`` (grey PNGs named by nanosecond timestamp,
    data.csv, sensor.yaml) and ``state_groundtruth_estimate0/data.csv`` with the body pose
    (``T_WB = T_WC T_BS^-1``) at ``truth_per_frame`` times the frame rate."""
    frames = list(frames)
    cam = root / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    camera = frames[0].camera
    assert camera is not None
    stamps = [epoch_ns + round(f.timestamp * 1e9) for f in frames]
    rows = ["#timestamp [ns],filename"]
    for stamp, frame in zip(stamps, frames):
        cv2.imwrite(str(cam / "data" / f"{stamp}.png"), frame.gray())
        rows.append(f"{stamp},{stamp}.png")
    (cam / "data.csv").write_text("\n".join(rows) + "\n")
    matrix = ", ".join(repr(float(v)) for v in EUROC_BODY_TO_CAMERA.reshape(-1))
    (cam / "sensor.yaml").write_text(
        "# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{matrix}]\n\n"
        f"rate_hz: 20\nresolution: [{camera.width}, {camera.height}]\ncamera_model: pinhole\n"
        f"intrinsics: [{camera.fx}, {camera.fy}, {camera.cx}, {camera.cy}] #fu, fv, cu, cv\n"
        f"distortion_model: radial-tangential\ndistortion_coefficients: [{', '.join(map(str, distortion))}]\n"
    )
    truth = root / "mav0" / "state_groundtruth_estimate0"
    truth.mkdir(parents=True)
    lines = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
             "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
             "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"]
    inverse = np.linalg.inv(EUROC_BODY_TO_CAMERA)
    for i, (stamp, frame) in enumerate(zip(stamps, frames)):
        assert frame.pose is not None
        body = frame.pose @ inverse
        q = quaternion_of(body)
        gap = (stamps[i + 1] - stamp) // truth_per_frame if i + 1 < len(stamps) else 5_000_000
        for k in range(truth_per_frame):  # the frame's own pose, then rows between frames (the same pose)
            values = [*body[:3, 3], q[3], q[0], q[1], q[2]] + [0.0] * 9
            lines.append(f"{stamp + k * gap}," + ",".join(repr(float(v)) for v in values))
    (truth / "data.csv").write_text("\n".join(lines) + "\n")
    return root


def write_kitti(root: Path, frames: Iterable[Frame], sequence: str = "00", baseline_m: float = 0.54) -> Path:
    """A KITTI odometry sequence: ``sequences/NN/image_0`` (grey) and ``image_2`` (colour)
    PNGs, ``times.txt``, ``calib.txt`` (P0..P3, Tr) and ``poses/NN.txt`` (camera 0's poses in
    the first frame's camera 0, 12 numbers per line). Camera 2 is written at camera 0's
    place; its calib line puts it 0.06 m to the left, as KITTI's does, and the poses are
    camera 0's."""
    frames = list(frames)
    folder = root / "sequences" / sequence
    (folder / "image_0").mkdir(parents=True)
    (folder / "image_2").mkdir(parents=True)
    camera = frames[0].camera
    assert camera is not None
    first = np.linalg.inv(frames[0].pose)
    poses, times = [], []
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / "image_0" / f"{i:06d}.png"), frame.gray())
        cv2.imwrite(str(folder / "image_2" / f"{i:06d}.png"), cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR))
        times.append(f"{frame.timestamp:e}")
        poses.append(" ".join(f"{v:e}" for v in (first @ frame.pose)[:3].reshape(-1)))
    k = camera.matrix

    def projection(x_offset_m: float) -> str:
        p = np.hstack([k, (k @ np.array([x_offset_m, 0.0, 0.0]))[:, None]])
        return " ".join(f"{v:e}" for v in p.reshape(-1))

    tr = " ".join(f"{v:e}" for v in np.eye(4)[:3].reshape(-1))
    (folder / "calib.txt").write_text(
        f"P0: {projection(0.0)}\nP1: {projection(-baseline_m)}\nP2: {projection(0.06)}\n"
        f"P3: {projection(0.06 - baseline_m)}\nTr: {tr}\n"
    )
    (folder / "times.txt").write_text("\n".join(times) + "\n")
    (root / "poses").mkdir(parents=True, exist_ok=True)
    (root / "poses" / f"{sequence}.txt").write_text("\n".join(poses) + "\n")
    return root


def write_video(path: Path, frames: Iterable[Frame], fps: float = 10.0, codec: str = "MJPG") -> Path:
    """The frames as a video file (MJPEG in AVI by default) at ``fps``."""
    frames = list(frames)
    height, width = frames[0].image.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, (width, height))
    assert writer.isOpened(), f"OpenCV cannot write {codec} to {path}"
    for frame in frames:
        writer.write(cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR))
    writer.release()
    return path
