"""Loop candidates and pose-graph refinement of a drifting chain of registrations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from slamfront.core.geometry import relative
from slamfront.core.trajectory import relative_pose_error
from slamfront_plugins.registrations.clouds import StepTimer, prepare_points
from slamfront_plugins.registrations.config import FeatureIcpConfig
from slamfront_plugins.registrations.pose_graph import Link, loop_candidates, refine


def _pose(yaw_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    pose[:3, 3] = position
    return pose


def test_loop_candidates_need_proximity_similar_view_and_a_gap() -> None:
    config = FeatureIcpConfig(loop_radius_m=1.0, loop_max_angle_deg=45, loop_min_gap=3, loop_max_per_frame=1)
    poses = {
        0: _pose(0, (0, 0, 0)),
        1: _pose(0, (0.5, 0, 0)),  # close to 0 but only one frame later
        2: _pose(0, (5, 0, 0)),
        3: _pose(0, (5.2, 0, 0)),
        4: _pose(170, (0.3, 0, 0)),  # near 0 and 1, looking the other way
        5: _pose(10, (0.6, 0, 0)),  # near 1 (closest) and 0: one candidate per frame
    }
    assert loop_candidates(poses, config) == [(1, 5)]
    suggested = [(2, 4), (0, 3), (3, 0), (7, 0)]  # a detector's matches; unknown frame 7 ignored
    assert loop_candidates(poses, config, suggested) == [(1, 5), (0, 3), (2, 4)]


def test_loop_edge_pulls_a_drifting_chain_back(shared_data: Path) -> None:
    """Six views of a real scan; the chain drifts 0.5 deg per link; the sixth view revisits the first."""
    scan = o3d.io.read_point_cloud(str(shared_data / "clouds" / "3dmatch_home_at" / "cloud_bin_2.ply"))
    world = np.asarray(scan.voxel_down_sample(0.03).points)
    x0, span = world[:, 0].min(), np.ptp(world[:, 0])
    truth = {k: _pose(8.0 * k, (0.25 * k, 0.05 * k, 0.0)) for k in range(5)}
    truth[5] = _pose(3.0, (0.05, 0.0, 0.05))  # back where it started
    windows = {k: (x0 + 0.1 * k * span, x0 + (0.1 * k + 0.6) * span) for k in range(5)}
    windows[5] = windows[0]
    config = FeatureIcpConfig(
        voxel_size_m=0.05, feature="none", initial_alignment="none", icp_method="point_to_plane", fallbacks=[],
        pose_graph=True, loop_radius_m=0.6, loop_min_gap=4, loop_max_angle_deg=30, loop_max_per_frame=1,
    )
    timer = StepTimer()
    clouds = {}
    for k, pose in truth.items():
        inside = world[(world[:, 0] >= windows[k][0]) & (world[:, 0] <= windows[k][1])]
        camera = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(inside @ pose[:3, :3] + -(pose[:3, :3].T @ pose[:3, 3])))
        clouds[k] = prepare_points(k, camera, config, timer)
    drift = _pose(0.5, (0.01, 0.0, 0.0))
    links = [Link(k, k - 1, relative(truth[k - 1], truth[k]) @ drift) for k in range(1, 6)]
    chained = {0: truth[0]}
    for link in links:
        chained[link.source] = chained[link.target] @ link.transform

    result = refine(clouds, chained, links, config, timer)

    assert result.refined and result.loop_edges.tolist() == [[0, 5]]
    frames = sorted(truth)
    stack = lambda poses: np.stack([poses[k] for k in frames])  # noqa: E731
    loop = np.array([[0, 5]])
    before = relative_pose_error(stack(truth), stack(chained), loop)
    after = relative_pose_error(stack(truth), stack(result.poses), loop)
    assert before.rotation_deg[0] > 2.4 and after.rotation_deg[0] < 0.6  # the loop closes (measured: 2.5 -> 0.35 deg)
    assert after.translation[0] < 0.7 * before.translation[0]  # measured: 4.9 -> 2.7 cm
    assert {"loop_registration", "pose_graph"} <= set(timer.seconds)
