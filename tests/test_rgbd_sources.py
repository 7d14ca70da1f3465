"""RGB-D sources on the shared samples and on TUM-layout fixtures; trajectory file readers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront.errors import DataError
from slamfront.formats.poses import read_kitti, read_pose_lines, read_redwood_log, read_tum, write_tum
from slamfront.formats.tum_rgbd import associate
from slamfront_plugins.sources.rgbd import RgbdFolder, TumRgbd


def _config(cls, **params):
    return cls.Config.model_validate(params)


def test_redwood_sample(shared_data: Path) -> None:
    source = RgbdFolder(_config(
        RgbdFolder, root=shared_data / "rgbd/redwood_sample", match_file="rgbd.match", poses="trajectory.log",
        pose_format="redwood_log", intrinsics_file="camera_primesense.json",
    ))
    frames = list(source.frames())
    assert len(frames) == len(source) == 5
    first = frames[0]
    assert first.image.shape == (480, 640, 3) and first.depth.shape == (480, 640)
    assert first.camera.fx == 525.0 and first.camera.cx == 319.5
    valid = first.depth[first.depth > 0]
    assert 0.3 < np.median(valid) < 5.0  # metres, an indoor scene
    expected = read_redwood_log(shared_data / "rgbd/redwood_sample/trajectory.log").poses[0]
    np.testing.assert_array_equal(first.pose, expected)


@pytest.mark.parametrize(
    ("folder", "camera", "scale"),
    [("room_sample", "slambook_room", 1000.0), ("icl_livingroom_sample", "icl_nuim", 5000.0)],
)
def test_pose_line_samples(shared_data: Path, folder: str, camera: str, scale: float) -> None:
    source = RgbdFolder(_config(RgbdFolder, root=shared_data / "rgbd" / folder, poses="pose.txt",
                                camera=camera, depth_scale=scale))
    frames = list(source.frames())
    assert [f.name for f in frames] == [f"{i}.png" for i in range(1, 6)]
    for frame in frames:
        assert frame.depth.shape == frame.image.shape[:2]
        assert 0.2 < np.median(frame.depth[frame.depth > 0]) < 8.0
        assert np.allclose(frame.pose[:3, :3] @ frame.pose[:3, :3].T, np.eye(3), atol=1e-6)
    # consecutive frames of a hand-held sequence move centimetres to a metre, not more
    steps = [np.linalg.norm(a.pose[:3, 3] - b.pose[:3, 3]) for a, b in zip(frames, frames[1:])]
    assert all(0.001 < s < 1.5 for s in steps)


def _tum_fixture(root: Path, n: int = 4, depth_shape: tuple[int, int] = (24, 32)) -> Path:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, depth, gt = ["# color images"], ["# depth maps"], ["# ground truth"]
    for i in range(n):
        t = 1305031102.0 + i / 30
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), np.full((24, 32, 3), 40 * i, np.uint8))
        cv2.imwrite(str(root / f"depth/{t + 0.004:.6f}.png"), np.full(depth_shape, 5000 * (i + 1), np.uint16))
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png")
        gt.append(f"{t + 0.001:.4f} {i * 0.1} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(depth) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


def test_tum_layout_fixture(tmp_path: Path) -> None:
    source = TumRgbd(_config(TumRgbd, root=_tum_fixture(tmp_path / "seq")))
    frames = list(source.frames())
    assert len(frames) == 4
    assert [float(f.depth[0, 0]) for f in frames] == [1.0, 2.0, 3.0, 4.0]
    assert [f.pose[0, 3] for f in frames] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert frames[0].camera.fx == 517.3  # fr1 by default


def test_tum_depth_of_the_wrong_size(tmp_path: Path) -> None:
    source = TumRgbd(_config(TumRgbd, root=_tum_fixture(tmp_path / "seq", depth_shape=(10, 10))))
    with pytest.raises(DataError, match=r"depth is 10x10 but the colour image is 32x24"):
        next(iter(source.frames()))


def test_tum_timestamps_that_cannot_be_associated(tmp_path: Path) -> None:
    root = _tum_fixture(tmp_path / "seq")
    (root / "depth.txt").write_text("100.0 depth/x.png\n")
    with pytest.raises(DataError, match=r"rgb.txt: no colour timestamp is within 0.02 s"):
        TumRgbd(_config(TumRgbd, root=root)).entries()


def test_unreadable_ground_truth_line_names_file_and_line(tmp_path: Path) -> None:
    root = _tum_fixture(tmp_path / "seq")
    with open(root / "groundtruth.txt", "a") as f:
        f.write("1305031103.0 0 0 zero 0 0 0 1\n")
    with pytest.raises(DataError, match=r"groundtruth.txt:6: not a number"):
        TumRgbd(_config(TumRgbd, root=root)).entries()


def test_missing_depth_names_the_frame(tmp_path: Path, shared_data: Path) -> None:
    root = tmp_path / "seq"
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    for name in ("1.png", "2.png"):
        cv2.imwrite(str(root / "color" / name), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(root / "depth/1.png"), np.zeros((8, 8), np.uint16))
    with pytest.raises(DataError, match=r"color/2.png: no depth image named 2"):
        RgbdFolder(_config(RgbdFolder, root=root)).entries()


def test_pose_count_must_match(tmp_path: Path, shared_data: Path) -> None:
    sample = shared_data / "rgbd/redwood_sample"
    root = tmp_path / "seq"
    for sub in ("color", "depth"):
        (root / sub).mkdir(parents=True)
        for path in sorted((sample / sub).iterdir())[:4]:
            (root / sub / path.name).symlink_to(path)
    (root / "trajectory.log").symlink_to(sample / "trajectory.log")
    source = RgbdFolder(_config(RgbdFolder, root=root, poses="trajectory.log", pose_format="redwood_log"))
    with pytest.raises(DataError, match=r"trajectory.log: 5 poses for 4 frames"):
        source.entries()


def test_trajectory_readers_round_trip(tmp_path: Path, shared_data: Path) -> None:
    gt = read_tum(shared_data / "trajectories/fr1_gt_vs_est/groundtruth.txt")
    assert len(gt) == 612  # 612 lines (the last one without a newline)
    back = read_tum(write_tum(tmp_path / "t.txt", gt))
    np.testing.assert_array_equal(back.timestamps, gt.timestamps)
    np.testing.assert_allclose(back.poses, gt.poses, atol=1e-12)
    lines = read_pose_lines(shared_data / "rgbd/room_sample/pose.txt")
    assert len(lines) == 5
    (tmp_path / "k.txt").write_text("1 0 0 2 0 1 0 3 0 0 1 4\n")
    assert read_kitti(tmp_path / "k.txt").positions.tolist() == [[2.0, 3.0, 4.0]]
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(DataError, match=r"bad.txt:1: expected 12 numbers"):
        read_kitti(tmp_path / "bad.txt")


def test_association_is_greedy_closest_first() -> None:
    # candidates: (0, 0) 0.012 s, (0, 1) 0.004 s, (1, 2) 0.001 s; closest first, one-to-one
    pairs = associate(np.array([0.0, 0.05]), np.array([0.012, 0.004, 0.049]), max_difference=0.02)
    assert pairs.tolist() == [[0, 1], [1, 2]]
    pairs = associate(np.array([1.0, 2.0]), np.array([2.005, 1.01]), 0.02)
    assert pairs.tolist() == [[0, 1], [1, 0]]
