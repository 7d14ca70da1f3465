"""Back-projection, relative pose error, the PLY writer and the Foxglove point cloud."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.clouds import back_project, transform_points
from slamfront.core.errors import CoreError
from slamfront.errors import DataError
from slamfront.formats.ply import write_ply
from slamfront.mcaplog.foxglove import point_cloud
from slamfront.messages import PointCloud
from slamfront_plugins.registrations.messages import CloudRegistration, RegisteredTrajectory

K = np.array([[500.0, 0.0, 319.5], [0.0, 510.0, 239.5], [0.0, 0.0, 1.0]])


def test_back_project_matches_open3d() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 6.0, (480, 640)).astype(np.float32)
    depth[::7, ::5] = 0.0  # no return
    depth[100:110, 200:210] = np.nan
    points, pixels = back_project(depth, K, min_depth=0.1, max_depth=4.0)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(640, 480, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    theirs = o3d.geometry.PointCloud.create_from_depth_image(
        o3d.geometry.Image(np.nan_to_num(depth)), intrinsic, depth_scale=1.0, depth_trunc=4.0
    )
    np.testing.assert_allclose(np.sort(points, axis=0), np.sort(np.asarray(theirs.points), axis=0), atol=1e-5)
    v, u = pixels[0]
    assert points[0, 2] == pytest.approx(depth[v, u])
    assert np.all((points[:, 2] > 0.1) & (points[:, 2] <= 4.0))


def test_back_project_stride_and_errors() -> None:
    depth = np.ones((4, 6), dtype=np.float32)
    points, pixels = back_project(depth, K, stride=2)
    assert len(points) == 6 and set(pixels[:, 0]) == {0, 2} and set(pixels[:, 1]) == {0, 2, 4}
    with pytest.raises(CoreError, match="stride"):
        back_project(depth, K, stride=0)
    with pytest.raises(CoreError, match=r"\(H, W\)"):
        back_project(np.ones((2, 2, 2)), K)


def test_transform_points_keeps_dtype() -> None:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    pose[:3, 3] = [1.0, 2.0, 3.0]
    moved = transform_points(pose, np.array([[1.0, 0.0, 0.0]], dtype=np.float32))
    assert moved.dtype == np.float32
    np.testing.assert_allclose(moved, [[1.0, 3.0, 3.0]], atol=1e-6)


def _poses(yaws_deg: list[float], xs: list[float]) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(xs), 1, 1))
    for k, (yaw, x) in enumerate(zip(yaws_deg, xs)):
        poses[k, :3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
        poses[k, 0, 3] = x
    return poses


def test_write_ply_round_trips_through_open3d(tmp_path: Path) -> None:
    points = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32)
    colors = np.random.default_rng(2).integers(0, 256, (50, 3)).astype(np.uint8)
    path = write_ply(tmp_path / "model.ply", points, colors)
    cloud = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(cloud.points), points, atol=1e-6)
    np.testing.assert_allclose(np.asarray(cloud.colors) * 255.0, colors, atol=1e-3)
    assert not (tmp_path / "model.ply.tmp").exists()
    write_ply(tmp_path / "plain.ply", points)
    assert not o3d.io.read_point_cloud(str(tmp_path / "plain.ply")).has_colors()
    with pytest.raises(DataError, match="colours must be"):
        write_ply(tmp_path / "bad.ply", points, colors[:3])
    with pytest.raises(DataError, match="cannot write"):
        write_ply(tmp_path / "missing" / "model.ply", points)


def test_foxglove_point_cloud_layout() -> None:
    points = np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, 9.0]], dtype=np.float32)
    colors = np.array([[255, 0, 10], [1, 2, 3]], dtype=np.uint8)
    message = point_cloud(points, 123, colors, "map")
    assert message.point_stride == 16 and message.frame_id == "map" and message.pose.orientation.w == 1.0
    assert [f.name for f in message.fields] == ["x", "y", "z", "red", "green", "blue", "alpha"]
    rows = np.frombuffer(message.data, dtype=np.uint8).reshape(2, 16)
    np.testing.assert_array_equal(rows[:, :12].copy().view("<f4"), points)
    np.testing.assert_array_equal(rows[:, 12:15], colors)
    assert (rows[:, 15] == 255).all()
    plain = point_cloud(points, 0)
    assert plain.point_stride == 12 and [f.name for f in plain.fields] == ["x", "y", "z"]


def test_registration_messages_round_trip() -> None:
    cloud = PointCloud(frame=3, role="aligned", points=np.ones((4, 3), np.float32), colors=np.zeros((4, 3), np.uint8))
    step = CloudRegistration(frame=3, outcome="aligned", pose=np.eye(4), target=2, transform=np.eye(4),
                             fitness=0.9, inlier_rmse=0.01, seconds={"icp": 0.5})
    trajectory = RegisteredTrajectory(frames=np.arange(2), poses=np.tile(np.eye(4), (2, 1, 1)),
                                      loop_edges=np.empty((0, 2), np.int64))
    for message in (cloud, step, trajectory):
        assert type(message).from_json(message.to_json()).same_as(message)
    assert [suffix for suffix, _ in cloud.foxglove(0)] == ["aligned_cloud"]
    assert [suffix for suffix, _ in step.foxglove(0)] == ["pose"]
    assert [suffix for suffix, _ in trajectory.foxglove(0)] == ["trajectory"]


def test_depth_overlap_is_full_for_the_same_view_and_zero_for_a_turned_back_camera() -> None:
    from slamfront.core.clouds import depth_overlap

    k = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    depth = np.full((48, 64), 2.0, dtype=np.float32)
    depth[:, :8] = 0.0  # no return: not counted
    assert depth_overlap(depth, k, depth, k, np.eye(4)) == 1.0
    turned = np.diag([-1.0, 1.0, -1.0, 1.0])  # 180 degrees about y: B's wall is behind A
    assert depth_overlap(depth, k, depth, k, turned) == 0.0
    shifted = np.eye(4)
    shifted[0, 3] = 0.5  # 25 px to the right at 2 m: B's columns 8..63 land on 33..88, of which 33..63 are in A
    assert depth_overlap(depth, k, depth, k, shifted) == pytest.approx(31 / 56)
    closer = np.eye(4)
    closer[2, 3] = -0.5  # 1.5 m where A measured 2 m: a different surface
    assert depth_overlap(depth, k, depth, k, closer) == 0.0
