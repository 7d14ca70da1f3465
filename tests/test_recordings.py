"""The recording sources on small generated recordings that mirror the real layouts:
ROS 1 / ROS 2 bags (every encoding, pose type and storage), EuRoC, KITTI odometry and
video; and what a user sees when a recording is not what the recipe says."""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from slamfront.core.retiming import equal_distance
from slamfront.frame import Frame
from slamfront.undistort import Undistortion
from slamfront_plugins.sources.euroc import Euroc
from slamfront_plugins.sources.kitti_odometry import KittiOdometry
from slamfront_plugins.sources.ros_bag import RosBag
from slamfront_plugins.sources.synthetic import SyntheticWorld
from slamfront_plugins.sources.video import Video
from tests.recordings import TOPICS, BagSpec, BagWriter, write_bag, write_euroc, write_kitti, write_video


@pytest.fixture(scope="module")
def frames() -> list[Frame]:
    """Two laps of a small synthetic street: RGB, depth, intrinsics and poses."""
    world = SyntheticWorld(SyntheticWorld.Config(mode="stream", laps=2, frames_per_traversal=10, route_length_m=60,
                                                 image_width=64, image_height=48))
    return list(world.frames())


def _bag_path(root: Path, spec: BagSpec, name: str) -> Path:
    return root / (f"{name}.bag" if spec.ros == 1 else name)


# --- bags: every encoding, pose type and storage ------------------------------------------

SPECS = {
    "ros2_mcap_rgb8_16UC1_posestamped": BagSpec(),
    "ros2_sqlite3_bgr8_32FC1_odometry": BagSpec(storage="sqlite3", image="bgr8", depth="32FC1", pose="Odometry"),
    "ros2_mcap_rgba8_compressed_depth_covariance": BagSpec(image="rgba8", depth="compressedDepth",
                                                           pose="PoseWithCovarianceStamped"),
    "ros2_mcap_bgra8_transformstamped": BagSpec(image="bgra8", depth=None, pose="TransformStamped"),
    "ros2_mcap_bayer_tf": BagSpec(image="bayer_rggb8", pose="tf"),
    "ros1_jpeg_compressed_depth_tf": BagSpec(ros=1, image="jpeg", depth="compressedDepth", pose="tf"),
    "ros1_png_32FC1_compressed_posestamped": BagSpec(ros=1, image="png", depth="compressedDepth32"),
    "ros1_mono8_no_pose": BagSpec(ros=1, image="mono8", pose=None),
    "ros1_mono16_odometry": BagSpec(ros=1, image="mono16", depth="32FC1", pose="Odometry"),
}


@pytest.mark.parametrize("name", list(SPECS))
def test_a_bag_gives_back_the_frames_recorded_in_it(frames: list[Frame], tmp_path: Path, name: str) -> None:
    spec = SPECS[name]
    path = write_bag(_bag_path(tmp_path, spec, name), frames, spec)
    source = RosBag(RosBag.Config(**spec.source_params(path)))
    got = list(source.frames())
    assert len(got) == len(source) == len(frames)
    assert source.statistics()["n_frames_dropped"] == 0 and source.statistics()["n_images_read"] == len(frames)
    lossless = spec.image in ("rgb8", "bgr8", "rgba8", "bgra8", "png")
    for mine, theirs in zip(got, frames):
        assert mine.index == theirs.index and mine.timestamp == pytest.approx(theirs.timestamp, abs=1e-9)
        expected = theirs.image if mine.image.ndim == 3 else theirs.gray()
        error = np.abs(mine.image.astype(np.float64) - expected).mean()
        assert error == 0 if lossless else error < 12, (name, error)  # JPEG, Bayer, mono16's 8 bits
        assert mine.camera == theirs.camera
        if spec.pose is None:
            assert mine.pose is None
        else:
            assert np.allclose(mine.pose, theirs.pose, atol=1e-9)
        if spec.depth is None:
            assert mine.depth is None
            continue
        assert mine.depth is not None and mine.depth.dtype == np.float32 and mine.depth.shape == theirs.depth.shape
        valid = theirs.depth > 0
        assert np.array_equal(mine.depth > 0, valid)
        gap = np.abs(mine.depth[valid] - theirs.depth[valid])
        # millimetres (0.5 mm rounding); 32FC1 exact; compressedDepth 32FC1 quantised inverse depth
        limit = {"16UC1": 5e-4 + 1e-6, "compressedDepth": 5e-4 + 1e-6, "32FC1": 0.0}.get(spec.depth, 0.02 * 40**2)
        assert gap.max() <= limit, (name, gap.max())
    truth = source.loop_ground_truth()
    assert (truth is None) == (spec.pose is None)


def test_a_single_mcap_or_db3_file_and_a_folder_without_metadata_are_bags(frames: list[Frame], tmp_path: Path) -> None:
    for storage, suffix in (("mcap", ".mcap"), ("sqlite3", ".db3")):
        spec = BagSpec(storage=storage)
        folder = write_bag(tmp_path / storage, frames[:4], spec)
        single = next(folder.glob(f"*{suffix}"))
        for path in (single, folder):
            assert len(list(RosBag(RosBag.Config(**spec.source_params(path))).frames())) == 4
        (folder / "metadata.yaml").unlink()  # a recording killed before rosbag2 wrote it
        assert len(list(RosBag(RosBag.Config(**spec.source_params(folder))).frames())) == 4


def test_start_step_limit_and_time_range_choose_image_messages(frames: list[Frame], tmp_path: Path) -> None:
    spec = BagSpec()
    path = write_bag(tmp_path / "bag", frames, spec)

    def names(**params: Any) -> list[int]:
        return [f.sequence_index for f in RosBag(RosBag.Config(**spec.source_params(path), **params)).frames()]

    assert names(start=2, step=3, limit=4) == [2, 5, 8, 11]
    assert len(RosBag(RosBag.Config(**spec.source_params(path), start=2, step=3, limit=4))) == 4
    dt = frames[1].timestamp - frames[0].timestamp
    window = RosBag(RosBag.Config(**spec.source_params(path), start_time_s=2.5 * dt, end_time_s=5.5 * dt, step=2))
    assert [f.timestamp for f in window.frames()] == pytest.approx([3 * dt, 5 * dt])  # start/step count from there


def test_images_without_depth_or_pose_in_tolerance_are_dropped_and_counted(
    frames: list[Frame], tmp_path: Path, cli: Any
) -> None:
    """Depth lost for frames 3 and 7, the pose of frame 5 late by 50 ms: three frames dropped,
    counted in metrics.json, the rest paired by nearest stamp (poses at 4x the image rate)."""
    spec = BagSpec(pose=None)
    path = tmp_path / "gaps"
    with BagWriter(path, spec) as writer:
        for frame in frames:
            stamp = round(frame.timestamp * 1e9)
            image = writer._image(stamp, frame.image)
            writer._write(spec.image_topic, image.__msgtype__, image, stamp)
            if frame.index not in (3, 7):
                depth = writer._depth(stamp + 4_000_000, frame.depth)  # 4 ms after the image
                writer._write(spec.depth_topic, depth.__msgtype__, depth, stamp + 4_000_000)
            writer._write(TOPICS["info"], "sensor_msgs/msg/CameraInfo", writer._info(stamp, frame), stamp)
            writer.spec = BagSpec(pose="PoseStamped")
            late = 50_000_000 if frame.index == 5 else 0
            for k in range(4):
                writer._pose(stamp + late + k * 30_000_000, frame.pose)
            writer.spec = spec
    params = {**BagSpec().source_params(path), "sync_tolerance_s": 0.02}
    source = RosBag(RosBag.Config(**params))
    got = list(source.frames())
    assert [f.sequence_index for f in got] == [i for i in range(len(frames)) if i not in (3, 5, 7)]
    assert source.statistics() == {
        "n_images_read": len(frames), "n_frames_dropped": 3, "n_frames_dropped_no_depth": 2,
        "n_frames_dropped_no_pose": 1, "n_frames_dropped_out_of_order": 0, "n_frames_resampled_out": 0,
    }
    assert [f.index for f in got] == list(range(len(got)))
    recipe = {
        "name": "gaps", "source": {"plugin": "ros_bag", "params": params},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour"}, "eval": {"plots": False},
    }
    (tmp_path / "gaps.yaml").write_text(yaml.safe_dump(recipe))
    code, _, err = cli("run", tmp_path / "gaps.yaml", "-o", tmp_path / "run", "-q")
    assert code == 0, err
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["n_frames"] == len(frames) - 3 and metrics["n_frames_dropped"] == 3
    assert metrics["n_frames_dropped_no_depth"] == 2 and metrics["n_frames_dropped_no_pose"] == 1
    # the ground truth of the frames given, stamped with their header times
    from slamfront.formats.poses import read_tum

    truth = read_tum(tmp_path / "run" / "groundtruth.tum")
    assert np.allclose(truth.timestamps, [f.timestamp for f in got], atol=1e-9)
    assert np.allclose(truth.poses, [f.pose for f in got], atol=1e-9)


# --- bad input: one line, exit 2 ------------------------------------------------------------


def _run_error(cli: Any, tmp_path: Path, params: dict[str, Any]) -> str:
    recipe = {"name": "bad", "source": {"plugin": "ros_bag", "params": params},
              "descriptor": {"plugin": "downsampled"}, "loop_detector": {"plugin": "nearest_neighbour"}}
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(recipe))
    code, out, err = cli("run", tmp_path / "bad.yaml", "-o", tmp_path / "out", "-q")
    assert code == 2 and "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_a_missing_topic_names_the_bags_topics_and_a_close_one(frames: list[Frame], tmp_path: Path, cli: Any) -> None:
    spec = BagSpec()
    path = write_bag(tmp_path / "bag", frames[:2], spec)
    line = _run_error(cli, tmp_path, {**spec.source_params(path), "image_topic": "/camera/color/image_rwa"})
    assert "no topic '/camera/color/image_rwa' (image_topic)" in line
    assert "did you mean '/camera/color/image_raw'" in line
    assert "/camera/aligned_depth_to_color/image_raw (sensor_msgs/msg/Image, 2)" in line
    assert "/ground_truth/pose (geometry_msgs/msg/PoseStamped, 2)" in line
    line = _run_error(cli, tmp_path, {**spec.source_params(path), "pose_topic": TOPICS["info"]})
    assert "pose_topic '/camera/color/camera_info' carries sensor_msgs/msg/CameraInfo, expected" in line


def test_an_unsupported_encoding_is_named(frames: list[Frame], tmp_path: Path, cli: Any) -> None:
    spec = BagSpec(depth=None, pose=None, camera_info=False)
    path = tmp_path / "yuv"
    with BagWriter(path, spec) as writer:
        message = writer.raw_image(0, np.zeros((4, 8, 2), np.uint8), "yuv422")
        writer._write(spec.image_topic, message.__msgtype__, message, 0)
    line = _run_error(cli, tmp_path, spec.source_params(path))
    assert "unsupported image encoding 'yuv422'" in line and f"{path}:{spec.image_topic}:0" in line


@pytest.mark.parametrize("damage", ["truncated", "garbage", "missing"])
def test_a_damaged_or_missing_bag_names_the_file(frames: list[Frame], tmp_path: Path, cli: Any, damage: str) -> None:
    spec = BagSpec(ros=1)
    path = write_bag(tmp_path / "robot.bag", frames, spec)
    if damage == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 40)
    else:
        path.unlink()
    line = _run_error(cli, tmp_path, spec.source_params(path))
    assert str(path) in line
    assert ("no such bag" in line) if damage == "missing" else ("not a readable ROS bag" in line or "damaged" in line)


def test_a_damaged_ros2_mcap_names_the_file(frames: list[Frame], tmp_path: Path, cli: Any) -> None:
    spec = BagSpec()
    folder = write_bag(tmp_path / "bag", frames, spec)
    single = next(folder.glob("*.mcap"))
    data = single.read_bytes()
    single.write_bytes(data[: len(data) * 2 // 3])
    line = _run_error(cli, tmp_path, spec.source_params(single))
    assert str(single) in line


# --- EuRoC, KITTI odometry, video -------------------------------------------------------------


def test_euroc_gives_the_camera_pose_from_the_body_ground_truth(frames: list[Frame], tmp_path: Path) -> None:
    root = write_euroc(tmp_path / "MH_01_easy", frames)
    source = Euroc(Euroc.Config(root=root))
    got = list(source.frames())
    assert len(got) == len(source) == len(frames)
    for mine, theirs in zip(got, frames):
        assert np.allclose(mine.pose, theirs.pose, atol=1e-9)  # T_WB T_BS: back to the camera
        assert np.array_equal(mine.image, theirs.gray()) and mine.camera == theirs.camera
        assert mine.timestamp - got[0].timestamp == pytest.approx(theirs.timestamp - frames[0].timestamp, abs=1e-6)
    assert source.loop_ground_truth() is not None
    # frames outside the ground truth's time span are dropped and counted
    csv = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:1] + lines[1 + 4 * 3:]) + "\n")  # no truth for the first 3 frames
    later = Euroc(Euroc.Config(root=root))
    assert len(list(later.frames())) == len(frames) - 3 and later.statistics()["n_frames_dropped"] == 3


def test_euroc_undistorts_with_the_sensor_yaml_distortion(frames: list[Frame], tmp_path: Path) -> None:
    """An image distorted by OpenCV's radial-tangential model comes back as the pinhole image."""
    frame = frames[0]
    camera = frame.camera
    assert camera is not None
    coefficients = np.array([-0.28, 0.07, 0.0002, 0.00002])
    # the distorted image: each of its pixels shows where its undistorted ray meets the pinhole image
    grid = np.stack(np.meshgrid(np.arange(camera.width), np.arange(camera.height)), -1).reshape(-1, 1, 2)
    ideal = cv2.undistortPoints(grid.astype(np.float64), camera.matrix, coefficients, P=camera.matrix).reshape(
        camera.height, camera.width, 2).astype(np.float32)
    distorted = cv2.remap(frame.gray(), ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR)
    back = Undistortion(camera, "radial-tangential", coefficients).image(distorted)
    inside = (slice(4, -4), slice(4, -4))
    undone = np.abs(back[inside].astype(float) - frame.gray()[inside]).mean()
    assert undone < 0.5 * np.abs(distorted[inside].astype(float) - frame.gray()[inside]).mean(), undone
    root = write_euroc(tmp_path / "seq", [Frame(**{**frame.__dict__, "image": cv2.cvtColor(distorted, cv2.COLOR_GRAY2RGB)})],
                       distortion=tuple(coefficients))
    image = next(Euroc(Euroc.Config(root=root, ground_truth=False)).frames()).image
    assert np.array_equal(image, back)


@pytest.mark.parametrize("camera", ["image_0", "image_2"])
def test_kitti_odometry_reads_calib_times_and_poses(frames: list[Frame], tmp_path: Path, camera: str) -> None:
    root = write_kitti(tmp_path / "kitti", frames, sequence="05")
    source = KittiOdometry(KittiOdometry.Config(root=root, sequence="5", camera=camera, step=2))
    got = list(source.frames())
    assert len(got) == len(source) == len(frames) // 2
    first = np.linalg.inv(frames[0].pose)
    for mine in got:
        theirs = frames[mine.sequence_index]
        assert mine.timestamp == pytest.approx(theirs.timestamp, abs=1e-5)
        assert mine.camera is not None and mine.camera.matrix == pytest.approx(theirs.camera.matrix)
        expected = first @ theirs.pose
        if camera == "image_2":  # camera 2 sits 6 cm left of camera 0 (calib.txt's P2)
            expected = expected @ np.array([[1, 0, 0, -0.06], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        assert np.allclose(mine.pose, expected, atol=1e-5)
        assert mine.image.ndim == (2 if camera == "image_0" else 3)
    truth = source.loop_ground_truth()
    assert truth is not None and len(truth.queries) == len(got)


def test_recordings_with_poses_resample_to_equal_distance(frames: list[Frame], tmp_path: Path, cli: Any) -> None:
    """SMART (Pepperell et al. 2014) on a recording: a stop keeps one frame, the rest one per resample_m."""
    dt = frames[1].timestamp - frames[0].timestamp
    stopped = frames[:5] + [dataclasses.replace(frames[4], timestamp=frames[4].timestamp + k * dt / 4) for k in (1, 2, 3)]
    stopped += frames[5:]
    truth = equal_distance(np.array([f.pose[:3, 3] for f in frames]), 5.0).tolist()  # 6 m per frame: all of them
    assert truth == list(range(len(frames)))
    spec = BagSpec()
    bag = RosBag(RosBag.Config(**spec.source_params(write_bag(tmp_path / "bag", stopped, spec)), resample_m=5.0))
    got = list(bag.frames())
    assert [f.timestamp for f in got] == pytest.approx([f.timestamp for f in frames], abs=1e-9)
    assert bag.statistics()["n_frames_resampled_out"] == 3 and bag.statistics()["n_frames_dropped"] == 0
    assert len(bag.loop_ground_truth().queries) == len(frames)
    wide = equal_distance(np.array([f.pose[:3, 3] for f in frames]), 12.0).tolist()
    euroc = Euroc(Euroc.Config(root=write_euroc(tmp_path / "MH_01", frames), resample_m=12.0, start=1))
    assert [f.sequence_index for f in euroc.frames()] == [1 + i for i in equal_distance(
        np.array([f.pose[:3, 3] for f in frames[1:]]), 12.0)]
    kitti = KittiOdometry(KittiOdometry.Config(root=write_kitti(tmp_path / "kitti", frames), resample_m=12.0))
    assert [f.sequence_index for f in kitti.frames()] == wide and len(kitti) == len(wide)
    assert len(kitti.loop_ground_truth().queries) == len(wide)
    code, _, err = cli("run", "demo", "--set", "source.plugin=euroc", "--set", "source.params={root: x, resample_m: 1, "
                       "ground_truth: false}", "-o", tmp_path / "out")
    assert code == 2 and "resample_m needs" in err and len(err.strip().splitlines()) == 1


def test_video_frames_carry_the_containers_timestamps(frames: list[Frame], tmp_path: Path) -> None:
    path = write_video(tmp_path / "drive.avi", frames, fps=10.0)
    got = list(Video(Video.Config(path=path)).frames())
    assert [round(f.timestamp, 6) for f in got] == [round(i / 10.0, 6) for i in range(len(frames))]
    assert np.abs(got[4].image.astype(float) - frames[4].image).mean() < 12  # MJPEG
    half = list(Video(Video.Config(path=path, fps=4.0, max_width=32, grey=True, camera="primesense")).frames())
    assert [round(f.timestamp, 6) for f in half] == [0.0, 0.3, 0.6, 0.9, 1.2, 1.5, 1.8]
    assert half[0].image.shape == (24, 32) and half[0].camera is not None and half[0].camera.width == 32
    assert half[0].camera.fx == pytest.approx(525.0 / 2)
    window = list(Video(Video.Config(path=path, start=2, step=3, limit=3)).frames())
    assert [f.sequence_index for f in window] == [2, 5, 8]


def test_a_file_that_is_not_a_video_is_one_line(tmp_path: Path, cli: Any) -> None:
    path = tmp_path / "notes.mp4"
    path.write_bytes(b"not a video" * 100)
    recipe = {"name": "v", "source": {"plugin": "video", "params": {"path": str(path)}},
              "descriptor": {"plugin": "downsampled"}, "loop_detector": {"plugin": "nearest_neighbour"}}
    (tmp_path / "v.yaml").write_text(yaml.safe_dump(recipe))
    code, _, err = cli("run", tmp_path / "v.yaml", "-o", tmp_path / "out", "-q")
    assert code == 2 and "Traceback" not in err and "notes.mp4" in err and len(err.strip().splitlines()) == 1, err


def test_compressed_depth_header_is_honoured(tmp_path: Path) -> None:
    """compressed_depth_image_transport's 32FC1 header (a, b): depth = a / (value - b)."""
    from types import SimpleNamespace

    from slamfront.formats.ros import compressed_depth_from_ros

    depth = np.array([[0.5, 2.0], [0.0, 40.0]], dtype=np.float32)
    a, b = 10100.0, 1.0 - 10100.0 / 50.0
    values = np.where(depth > 0, a / np.maximum(depth, 1e-6) + b, 0).astype(np.uint16)
    ok, png = cv2.imencode(".png", values)
    message = SimpleNamespace(format="32FC1; compressedDepth png", data=struct.pack("<iff", 0, a, b) + png.tobytes())
    back = compressed_depth_from_ros(message, "x")
    assert back[1, 0] == 0 and np.allclose(back, depth, rtol=0.02)
    message.format = "16UC1; compressedDepth rvl"
    with pytest.raises(Exception, match="unsupported compressed depth format"):
        compressed_depth_from_ros(message, "x")
