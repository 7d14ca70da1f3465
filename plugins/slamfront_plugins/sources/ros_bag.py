"""The ``ros_bag`` source: frames from a ROS 1 or ROS 2 recording, read without ROS.

Bags are read with ``rosbags`` (Apache-2.0; pure Python, reads ROS 1 ``.bag`` and ROS 2
bags in MCAP and sqlite3 storage, deserialises CDR and ROS 1 messages from the types the
bag itself records). ``mcap-ros2-support`` reads only ROS 2 MCAP files, so ROS 1 bags and
sqlite3 bags would need a second reader; ``rosbags`` is also what ``evo`` uses.

Messages are streamed in the order they were recorded and paired by header stamp
(:class:`slamfront.core.sync.StreamPairing`): only the few messages around the present
are held, whatever the bag's size.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import Camera, DataError, Frame, PluginConfig, Source
from slamfront.core.geometry import pose_from_quaternion
from slamfront.core.loops import LoopGroundTruth
from slamfront.core.retiming import DistanceSampler
from slamfront.core.sync import Paired, StreamPairing
from slamfront.data import DataPath
from slamfront.formats import ros
from slamfront.suggest import did_you_mean
from slamfront.undistort import Undistortion
from slamfront_plugins.sources.recording import (
    OdometryResampling,
    TimedRecordingConfig,
    given_camera,
    n_selected,
    revisit_truth,
)
from slamfront_plugins.sources.rgbd import Intrinsics, KnownCamera

logger = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
TF_TOPICS = ("/tf", "/tf_static")


class RosBagError(DataError):
    """A bag that cannot be used: missing, damaged, or without the topics a recipe names."""


class RosBag(Source):
    """Frames from a ROS 1 or ROS 2 bag (MCAP or sqlite3 storage), read without ROS.

    A ROS 1 ``.bag``, a rosbag2 folder (with ``metadata.yaml``), or a single
    ``.mcap``/``.db3`` file. One image topic gives the frames (``sensor_msgs/Image`` in any common encoding, or
    ``CompressedImage`` JPEG/PNG); depth (16UC1 millimetres, 32FC1 metres, or
    ``compressedDepth``) and a ground-truth pose (``PoseStamped``,
    ``PoseWithCovarianceStamped``, ``Odometry``, ``TransformStamped``, or the ``/tf``
    tree between two named frames) are paired to each image by nearest header stamp
    within ``sync_tolerance_s``; an image without one is dropped and counted
    (``n_frames_dropped_*`` in metrics.json). Intrinsics come from ``CameraInfo`` (images
    are undistorted when it gives a distortion), else from ``camera``. Loop ground truth
    for a stream comes from the poses: a frame revisits the frames within
    ``revisit_radius_m`` that the camera had left (gone farther than ``leave_radius_m``).
    """

    name = "ros_bag"

    class Config(TimedRecordingConfig, OdometryResampling):
        path: DataPath = Field(description="the bag: a ROS 1 .bag, a rosbag2 folder, or a .mcap/.db3 file")
        image_topic: str = Field(description="sensor_msgs/Image or CompressedImage topic: one frame per message")
        depth_topic: str | None = Field(None, description="depth registered to the image (Image 16UC1/32FC1 or "
                                        "CompressedImage compressedDepth)")
        camera_info_topic: str | None = Field(None, description="sensor_msgs/CameraInfo of the image topic")
        pose_topic: str | None = Field(None, description="ground truth: PoseStamped, PoseWithCovarianceStamped, "
                                       "Odometry or TransformStamped")
        tf_parent_frame: str | None = Field(None, description="ground truth from /tf: the world frame (e.g. map)")
        tf_child_frame: str | None = Field(None, description="ground truth from /tf: the camera's frame")
        camera_in_pose_frame: list[float] | None = Field(
            None, min_length=7, max_length=7,
            description="the camera's pose in the frame the ground truth tracks, tx ty tz qx qy qz qw (a body "
            "or base_link pose to the camera's optical frame: z forward, x right, y down); default identity",
        )
        camera: Intrinsics | KnownCamera | None = Field(
            None, description="intrinsics when the bag has no CameraInfo (overrides it when given)"
        )
        undistort: bool = Field(True, description="undistort images (and depth) by the CameraInfo's distortion")
        depth_scale: float = Field(1000.0, gt=0, description="16-bit depth units per metre (1000: millimetres)")
        sync_tolerance_s: float = Field(0.02, ge=0, description="largest stamp difference of image-depth and "
                                        "image-pose pairs; an image without a partner is dropped")
        timestamps: Literal["header", "receive"] = Field(
            "header", description="frame times from the messages' header stamps, or from when the bag received them"
        )
        @model_validator(mode="after")
        def _one_ground_truth(self) -> RosBag.Config:
            if self.pose_topic is not None and (self.tf_parent_frame or self.tf_child_frame):
                raise ValueError("give either pose_topic or tf_parent_frame/tf_child_frame, not both")
            if bool(self.tf_parent_frame) != bool(self.tf_child_frame):
                raise ValueError("ground truth from /tf needs both tf_parent_frame and tf_child_frame")
            if self.resample_m > 0 and self.pose_topic is None and not self.tf_parent_frame:
                raise ValueError("resample_m needs poses: give pose_topic (a pose or odometry topic) or the /tf frames")
            return self

    config: Config

    def __init__(self, config: PluginConfig | None = None) -> None:
        super().__init__(config)
        self._positions: list[np.ndarray] = []
        self._counts = _Counts()
        self._streamed = False

    # --- opening -------------------------------------------------------------------------

    @contextlib.contextmanager
    def _open(self) -> Iterator[_Bag]:
        path = Path(self.config.path)
        if not path.exists():
            raise RosBagError(f"{path}: no such bag (a .bag or .mcap file, or a rosbag2 folder)")
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        paths = [path]
        # a rosbag2 folder without metadata.yaml: its one storage file (as `ros2 bag` leaves it when killed)
        if path.is_dir() and not (path / "metadata.yaml").exists():
            files = sorted([*path.glob("*.mcap"), *path.glob("*.db3")])
            if len(files) != 1:
                raise RosBagError(f"{path}: a rosbag2 folder needs metadata.yaml (or exactly one .mcap/.db3 file)")
            paths = files
        try:
            reader = AnyReader(paths, default_typestore=get_typestore(Stores.LATEST))
            reader.open()
        except Exception as exc:  # noqa: BLE001 (a damaged file raises whatever the reader meets)
            raise RosBagError(f"{path}: not a readable ROS bag ({_reason(exc)})") from None
        try:
            yield _Bag(path, reader)
        finally:
            with contextlib.suppress(Exception):
                reader.close()

    def _connections(self, bag: _Bag) -> _Topics:
        c = self.config
        image = bag.require(c.image_topic, "image_topic", (IMAGE, COMPRESSED))
        depth = bag.require(c.depth_topic, "depth_topic", (IMAGE, COMPRESSED)) if c.depth_topic else None
        info = bag.require(c.camera_info_topic, "camera_info_topic", (CAMERA_INFO,)) if c.camera_info_topic else None
        pose = bag.require(c.pose_topic, "pose_topic", ros.POSE_TYPES) if c.pose_topic else None
        tf = []
        if c.tf_parent_frame:
            tf = [conn for conn in bag.reader.connections if conn.topic in TF_TOPICS and conn.msgtype == TF_MESSAGE]
            if not tf:
                raise RosBagError(
                    f"{bag.path}: ground truth from /tf, but the bag has no /tf or /tf_static topic; {bag.listing()}"
                )
        return _Topics(image, depth, info, pose, tf)

    def check(self, stages: Any) -> None:
        """Open the bag and find its topics before the first frame (one clear line if not)."""
        with self._open() as bag:
            self._connections(bag)

    def __len__(self) -> int:
        # with resample_m, an upper bound: which frames the poses keep is known only by streaming them
        with self._open() as bag:
            return n_selected(self._connections(bag).image.msgcount, self.config)

    # --- streaming -----------------------------------------------------------------------

    def frames(self) -> Iterator[Frame]:
        self._positions = []
        self._counts = _Counts()
        self._streamed = False
        yield from self._stream(decode=True)
        self._streamed = True

    def statistics(self) -> dict[str, int]:
        """Counters for metrics.json: images read, frames given, and images dropped, by reason."""
        return self._counts.as_dict()

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        if not self.config.pose_topic and not self.config.tf_parent_frame:
            return None
        if not self._positions and not self._streamed:
            # asked before the frames were read (a --max-frames hint): read the poses alone
            self._positions = []
            for _ in self._stream(decode=False):
                pass
        return revisit_truth(self._positions, self.config)

    def _stream(self, decode: bool) -> Iterator[Frame]:
        c = self.config
        tolerance = round(c.sync_tolerance_s * 1e9)
        extrinsic = (
            pose_from_quaternion(np.array(c.camera_in_pose_frame[:3]), np.array(c.camera_in_pose_frame[3:]))
            if c.camera_in_pose_frame is not None else None
        )
        counts = self._counts if decode else _Counts()
        sampler = DistanceSampler(c.resample_m) if c.resample_m > 0 else None
        with self._open() as bag:
            topics = self._connections(bag)
            lens = _Lens(c.camera, c.undistort)
            if topics.info is not None:
                first = bag.first(topics.info)
                if first is None:
                    raise RosBagError(f"{bag.path}: camera_info_topic {c.camera_info_topic!r} has no messages")
                lens.update_from(first, f"{bag.path}:{c.camera_info_topic}")
            tree = ros.TransformTree() if topics.tf else None
            partners = [name for name, conn in (("depth", topics.depth), ("pose", topics.pose)) if conn is not None]
            if tree is not None:
                partners.append("pose")
            pairing = StreamPairing(partners, tolerance)
            if tree is not None and not any(conn.topic == "/tf" for conn in topics.tf):
                pairing.streams["pose"].ended = True  # a static tree: nothing later can change it
            start, stop = bag.time_range(c.start_time_s, c.end_time_s)
            wanted = [topics.image, *(x for x in (topics.depth, topics.info, topics.pose) if x), *topics.tf]
            role = {conn.id: name for name, conn in (("pose", topics.pose), ("info", topics.info),
                                                      ("depth", topics.depth), ("image", topics.image)) if conn}
            image_number = -1
            last_stamp: int | None = None
            for connection, received, raw in bag.messages(wanted, start, stop):
                decided: list[Paired] = []
                topic = connection.topic
                if role.get(connection.id) == "image":
                    image_number += 1
                    if image_number < c.start or (image_number - c.start) % c.step:
                        continue
                    counts.images_read += 1
                    message = bag.deserialize(raw, connection, image_number)
                    stamp = ros.stamp_ns(message) if c.timestamps == "header" else received
                    decided = pairing.add_primary(stamp, received, (image_number, message, connection.msgtype))
                elif role.get(connection.id) == "depth":
                    message = bag.deserialize(raw, connection)
                    stamp = ros.stamp_ns(message) if c.timestamps == "header" else received
                    decided = pairing.add_partner("depth", stamp, received, (message, connection.msgtype))
                elif role.get(connection.id) == "info":
                    lens.update_from(bag.deserialize(raw, connection), f"{bag.path}:{topic}")
                    continue
                elif role.get(connection.id) == "pose":
                    message = bag.deserialize(raw, connection)
                    stamp = ros.stamp_ns(message) if c.timestamps == "header" else received
                    pose = ros.pose_from_ros(message, connection.msgtype, f"{bag.path}:{topic}")
                    decided = pairing.add_partner("pose", stamp, received, pose)
                elif tree is not None:
                    message = bag.deserialize(raw, connection)
                    newest = None
                    for transform in message.transforms:
                        when = ros.stamp_ns(transform)
                        matrix = ros.transform_from_ros(transform.transform, f"{bag.path}:{topic}")
                        tree.add(transform.header.frame_id, transform.child_frame_id, when, matrix,
                                 static=topic == "/tf_static")
                        newest = when if newest is None else max(newest, when)
                    if topic == "/tf" and newest is not None:
                        decided = pairing.add_partner("pose", newest, received, None)
                for paired in decided:
                    frame = self._frame(paired, bag, topics, lens, tree, extrinsic, tolerance, decode, counts,
                                        last_stamp, sampler)
                    if frame is not None:
                        last_stamp = paired.stamp
                        yield frame
                        if c.limit is not None and counts.frames >= c.limit:
                            return
                if tree is not None and decided:
                    tree.forget_before(decided[-1].stamp - tolerance)
            for paired in pairing.finish():
                frame = self._frame(paired, bag, topics, lens, tree, extrinsic, tolerance, decode, counts, last_stamp,
                                    sampler)
                if frame is not None:
                    last_stamp = paired.stamp
                    yield frame
                    if c.limit is not None and counts.frames >= c.limit:
                        return
        if counts.frames == 0 and decode:
            raise RosBagError(f"{Path(c.path)}: no frame: {counts.explain(c)}")

    def _frame(
        self, paired: Paired, bag: _Bag, topics: _Topics, lens: _Lens, tree: ros.TransformTree | None,
        extrinsic: np.ndarray | None, tolerance: int, decode: bool, counts: _Counts, last_stamp: int | None,
        sampler: DistanceSampler | None,
    ) -> Frame | None:
        """The frame of a decided image, or None when it is dropped (and counted)."""
        c = self.config
        number, message, msgtype = paired.item
        what = f"{bag.path}:{c.image_topic}:{number}"
        depth_partner = paired.partners.get("depth")
        if topics.depth is not None and depth_partner is None:
            counts.dropped_no_depth += 1
            return None
        pose = None
        if topics.pose is not None:
            found = paired.partners.get("pose")
            pose = None if found is None else found[1]
        elif tree is not None:
            pose = tree.lookup(c.tf_parent_frame or "", c.tf_child_frame or "", paired.stamp, tolerance)
        if (topics.pose is not None or tree is not None) and pose is None:
            counts.dropped_no_pose += 1
            return None
        if last_stamp is not None and paired.stamp <= last_stamp:
            counts.dropped_out_of_order += 1
            return None
        if pose is not None and extrinsic is not None:
            pose = pose @ extrinsic
        if sampler is not None and pose is not None and not sampler.keep(pose[:3, 3]):
            counts.resampled_out += 1
            return None
        index = counts.frames
        counts.frames += 1
        if pose is not None:
            self._positions.append(pose[:3, 3].copy())
        if not decode:
            return Frame(index=index, timestamp=paired.stamp / 1e9, image=np.zeros((1, 1), np.uint8), pose=pose)
        image = (ros.image_from_ros(message, what) if msgtype == IMAGE
                 else ros.compressed_image_from_ros(message, what))
        depth = None
        if depth_partner is not None:
            depth_message, depth_type = depth_partner[1]
            depth_what = f"{bag.path}:{c.depth_topic}@{depth_partner[0]}"
            depth = self._depth(depth_message, depth_type, depth_what)
            if depth.shape != image.shape[:2]:
                raise RosBagError(
                    f"{depth_what}: depth is {depth.shape[1]}x{depth.shape[0]} but the image is "
                    f"{image.shape[1]}x{image.shape[0]}: use the depth topic registered (aligned) to the image"
                )
        camera = lens.camera_for(image, what)
        if lens.undistortion is not None:
            image = lens.undistortion.image(image)
            depth = None if depth is None else lens.undistortion.depth(depth)
        return Frame(
            index=index, timestamp=paired.stamp / 1e9, image=image, traversal="stream",
            sequence_index=number, name=f"{c.image_topic}:{number}", depth=depth, camera=camera, pose=pose,
        )

    def _depth(self, message: Any, msgtype: str, what: str) -> np.ndarray:
        scale = self.config.depth_scale
        if msgtype == IMAGE:
            return ros.depth_from_ros(message, what, scale)
        if "compresseddepth" in str(message.format).lower():
            return ros.compressed_depth_from_ros(message, what, scale)
        from slamfront.imageio import decode_image

        raw = decode_image(bytes(message.data), what, "unchanged")
        if raw.ndim != 2 or raw.dtype != np.uint16:
            raise RosBagError(f"{what}: a compressed depth image must be 16-bit, one channel; got {raw.dtype} "
                              f"{raw.shape} ({message.format!r})")
        return raw.astype(np.float32) / np.float32(scale)


@dataclass
class _Counts:
    images_read: int = 0
    frames: int = 0
    dropped_no_depth: int = 0
    dropped_no_pose: int = 0
    dropped_out_of_order: int = 0
    resampled_out: int = 0
    """Left out by ``resample_m`` (closer than it to the last frame kept): chosen, not lost."""

    def as_dict(self) -> dict[str, int]:
        dropped = self.dropped_no_depth + self.dropped_no_pose + self.dropped_out_of_order
        return {
            "n_images_read": self.images_read, "n_frames_dropped": dropped,
            "n_frames_dropped_no_depth": self.dropped_no_depth, "n_frames_dropped_no_pose": self.dropped_no_pose,
            "n_frames_dropped_out_of_order": self.dropped_out_of_order, "n_frames_resampled_out": self.resampled_out,
        }

    def explain(self, config: RosBag.Config) -> str:
        if self.images_read == 0:
            return f"no message of {config.image_topic} in the range read (start, step, start_time_s, end_time_s)"
        return (
            f"all {self.images_read} images were dropped ({self.dropped_no_depth} without depth, "
            f"{self.dropped_no_pose} without a pose within sync_tolerance_s = {config.sync_tolerance_s} s, "
            f"{self.dropped_out_of_order} out of order); check the topics' stamps or raise sync_tolerance_s"
        )


@dataclass
class _Topics:
    image: Any
    depth: Any
    info: Any
    pose: Any
    tf: list[Any] = field(default_factory=list)


@dataclass
class _Lens:
    """The camera of the frames: given, or from the latest CameraInfo (with its undistortion)."""

    given: Intrinsics | KnownCamera | None
    undistort: bool
    camera: Camera | None = None
    undistortion: Undistortion | None = None
    _info: tuple[Any, ...] | None = None

    def update_from(self, message: Any, what: str) -> None:
        if self.given is not None:
            return
        camera, model, coefficients = ros.camera_from_ros(message, what)
        key = (camera, model, tuple(coefficients.tolist()))
        if key == self._info:
            return
        self._info = key
        self.camera = camera
        needed = self.undistort and Undistortion.needed(model, coefficients)
        self.undistortion = Undistortion(camera, model, coefficients) if needed else None

    def camera_for(self, image: np.ndarray, what: str) -> Camera | None:
        height, width = image.shape[:2]
        if self.given is not None:
            return given_camera(self.given, width, height)
        if self.camera is None:
            return None
        if (self.camera.width, self.camera.height) not in ((width, height), (0, 0)):
            raise RosBagError(
                f"{what}: the image is {width}x{height} but its CameraInfo is for {self.camera.width}x"
                f"{self.camera.height}; name the CameraInfo of this image topic, or give `camera`"
            )
        if (self.camera.width, self.camera.height) == (0, 0):
            self.camera = Camera(self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy, width, height)
        return self.camera


class _Bag:
    """An open bag: its connections, and reading them with damage said in one line."""

    def __init__(self, path: Path, reader: Any) -> None:
        self.path = path
        self.reader = reader

    def listing(self) -> str:
        topics: dict[str, tuple[str, int]] = {}
        for conn in self.reader.connections:
            known = topics.get(conn.topic)
            topics[conn.topic] = (conn.msgtype, conn.msgcount + (known[1] if known else 0))
        shown = [f"{t} ({kind}, {n})" for t, (kind, n) in sorted(topics.items())]
        more = f", and {len(shown) - 40} more" if len(shown) > 40 else ""
        return "the bag's topics: " + (", ".join(shown[:40]) + more if shown else "none")

    def require(self, topic: str, field_name: str, types: tuple[str, ...]) -> Any:
        found = [conn for conn in self.reader.connections if conn.topic == topic]
        if not found:
            known = sorted({conn.topic for conn in self.reader.connections})
            hint = did_you_mean(topic, known, "topics")
            hint = f"{hint}; " if hint.startswith("did you mean") else ""
            raise RosBagError(f"{self.path}: no topic {topic!r} ({field_name}); {hint}{self.listing()}")
        accepted = [conn for conn in found if conn.msgtype in types or conn.msgtype.replace("/msg/", "/") in
                    {t.replace("/msg/", "/") for t in types}]
        if not accepted:
            raise RosBagError(
                f"{self.path}: {field_name} {topic!r} carries {found[0].msgtype}, expected "
                f"{' or '.join(types)}; {self.listing()}"
            )
        if len(accepted) > 1:
            logger.warning("%s: %s has %d connections; reading the first", self.path, topic, len(accepted))
        return accepted[0]

    def time_range(self, start_s: float | None, end_s: float | None) -> tuple[int | None, int | None]:
        if start_s is None and end_s is None:
            return None, None
        origin = int(self.reader.start_time)
        return (
            None if start_s is None else origin + round(start_s * 1e9),
            None if end_s is None else origin + round(end_s * 1e9),
        )

    def messages(self, connections: list[Any], start: int | None, stop: int | None) -> Iterator[tuple[Any, int, Any]]:
        iterator = iter(self.reader.messages(connections=connections, start=start, stop=stop))
        while True:
            try:
                item = next(iterator)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 (a damaged file raises whatever the reader meets)
                raise RosBagError(f"{self.path}: damaged bag ({_reason(exc)})") from None
            yield item

    def first(self, connection: Any) -> Any:
        for conn, _, raw in self.messages([connection], None, None):
            return self.deserialize(raw, conn)
        return None

    def deserialize(self, raw: Any, connection: Any, number: int | None = None) -> Any:
        try:
            return self.reader.deserialize(raw, connection.msgtype)
        except Exception as exc:  # noqa: BLE001 (a damaged message raises whatever the decoder meets)
            at = f" message {number}" if number is not None else ""
            raise RosBagError(f"{self.path}: {connection.topic}{at}: damaged message ({_reason(exc)})") from None


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
