"""Known rigid transforms of real clouds are recovered (rotation < 1 deg, translation < 1 cm).

The source is the cloud moved by a known transform, with sensor-like noise, and (for
the 3DMatch scan) cropped so the two overlap only partly, as consecutive scans do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.geometry import invert, rotation_angle_deg
from slamfront_plugins.registrations.clouds import StepTimer, prepare_points
from slamfront_plugins.registrations.config import FeatureIcpConfig
from slamfront_plugins.registrations.pairwise import align

METHODS = {
    "fpfh+ransac+icp": dict(feature="fpfh", initial_alignment="ransac"),
    "fpfh+fgr+icp": dict(feature="fpfh", initial_alignment="fgr"),
    # PFH is quadratic in the neighbourhood size: 40 neighbours keep the test quick
    "pfh+ransac+icp": dict(feature="pfh", initial_alignment="ransac", feature_max_nn=40),
}
CLOUDS = {
    # voxel and ICP distance scale with the object: the bunny is 15 cm, the scan 2.3 m
    "bunny": dict(
        file="bunny_res3.ply", pre_voxel=None, crop=None, noise=0.0003, viewpoint=(0.0, 0.1, 0.6),
        config=dict(voxel_size_m=0.005, icp_distance_m=0.01, outlier_neighbours=0, min_points=50),
        motion=((25.0, -40.0, 30.0), (0.06, -0.04, 0.03)),
    ),
    "3dmatch": dict(
        file="3dmatch_home_at/cloud_bin_2.ply", pre_voxel=0.02, crop=0.25, noise=0.002, viewpoint=(0.0, 0.0, 0.0),
        config=dict(voxel_size_m=0.05, icp_distance_m=0.05, icp_method="point_to_plane"),
        motion=((10.0, 35.0, -15.0), (0.4, -0.25, 0.15)),
    ),
}


def _clouds(shared_data: Path, spec: dict) -> tuple[o3d.geometry.PointCloud, o3d.geometry.PointCloud, np.ndarray]:
    """(source, target, true source -> target transform)."""
    cloud = o3d.io.read_point_cloud(str(shared_data / "clouds" / spec["file"]))
    if spec["pre_voxel"]:
        cloud = cloud.voxel_down_sample(spec["pre_voxel"])  # keeps the test quick: 347k points -> ~40k
    points = np.asarray(cloud.points)
    rng = np.random.default_rng(7)
    target_points, source_points = points, points
    if spec["crop"]:
        x = points[:, 0]
        low, high = np.quantile(x, [spec["crop"], 1 - spec["crop"]])
        target_points, source_points = points[x <= high], points[x >= low]
    angles, shift = spec["motion"]
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    motion[:3, 3] = shift
    moved = source_points @ motion[:3, :3].T + motion[:3, 3] + rng.normal(0, spec["noise"], source_points.shape)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(moved))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target_points))
    return source, target, invert(motion)


@pytest.mark.parametrize(
    ("cloud_name", "method"),
    [("bunny", "fpfh+ransac+icp"), ("bunny", "fpfh+fgr+icp"), ("bunny", "pfh+ransac+icp"),
     ("3dmatch", "fpfh+ransac+icp"), ("3dmatch", "fpfh+fgr+icp")],
)
def test_known_transform_is_recovered(shared_data: Path, cloud_name: str, method: str) -> None:
    spec = CLOUDS[cloud_name]
    config = FeatureIcpConfig(**spec["config"], **METHODS[method], fallbacks=[])
    source, target, truth = _clouds(shared_data, spec)
    viewpoint = np.array(spec["viewpoint"])
    moved_viewpoint = invert(truth)[:3, :3] @ viewpoint + invert(truth)[:3, 3]
    timer = StepTimer()
    prepared_target = prepare_points(0, target, config, timer, viewpoint)
    prepared_source = prepare_points(1, source, config, timer, moved_viewpoint)
    alignment, attempts = align(prepared_source, prepared_target, np.eye(4), np.eye(4), config, timer, seed=1)
    error = invert(truth) @ alignment.transform
    assert alignment.passed, alignment.problem
    assert alignment.method == method
    assert rotation_angle_deg(error) < 1.0
    assert np.linalg.norm(error[:3, 3]) < 0.01
    assert len(attempts) == 1 and {"features", "initial_alignment", "icp"} <= set(timer.seconds)


def test_icp_alone_fails_from_far_and_the_check_says_so(shared_data: Path) -> None:
    """ICP from identity cannot undo a 45-degree turn: the fitness check must reject it."""
    spec = CLOUDS["3dmatch"]
    config = FeatureIcpConfig(**spec["config"], feature="none", initial_alignment="none", fallbacks=[])
    source, target, truth = _clouds(shared_data, {**spec, "motion": ((0.0, 45.0, 0.0), (0.5, 0.0, 0.3))})
    timer = StepTimer()
    prepared_target = prepare_points(0, target, config, timer)
    prepared_source = prepare_points(1, source, config, timer, invert(truth)[:3, 3])
    alignment, _ = align(prepared_source, prepared_target, np.eye(4), np.eye(4), config, timer, seed=1)
    assert not alignment.passed and alignment.problem.startswith("fitness")
    assert rotation_angle_deg(invert(truth) @ alignment.transform) > 10


def test_ransac_is_deterministic_for_a_seed(shared_data: Path) -> None:
    spec = CLOUDS["bunny"]
    config = FeatureIcpConfig(**spec["config"], **METHODS["fpfh+ransac+icp"], fallbacks=[])
    source, target, _ = _clouds(shared_data, spec)
    timer = StepTimer()
    prepared = [prepare_points(k, cloud, config, timer) for k, cloud in enumerate((target, source))]
    first, _ = align(prepared[1], prepared[0], np.eye(4), np.eye(4), config, timer, seed=5)
    second, _ = align(prepared[1], prepared[0], np.eye(4), np.eye(4), config, timer, seed=5)
    np.testing.assert_array_equal(first.transform, second.transform)


def test_previous_motion_fallback_rescues_a_failed_alignment(shared_data: Path) -> None:
    """ICP from identity fails at 45 degrees; the previous-motion guess (within 5 deg) succeeds."""
    spec = CLOUDS["3dmatch"]
    config = FeatureIcpConfig(
        **spec["config"], feature="none", initial_alignment="none", fallbacks=["wider", "previous_motion"]
    )
    source, target, truth = _clouds(shared_data, {**spec, "motion": ((0.0, 45.0, 0.0), (0.5, 0.0, 0.3))})
    timer = StepTimer()
    prepared_target = prepare_points(0, target, config, timer)
    prepared_source = prepare_points(1, source, config, timer, invert(truth)[:3, 3])
    nearly = truth.copy()
    nearly[:3, :3] = Rotation.from_euler("y", 4, degrees=True).as_matrix() @ truth[:3, :3]
    alignment, attempts = align(prepared_source, prepared_target, np.eye(4), nearly, config, timer, seed=1)
    assert [a.method for a in attempts] == ["icp", "icp (wider)", "previous motion+icp"]
    assert [a.passed for a in attempts] == [False, False, True]
    assert alignment is attempts[-1]
    assert rotation_angle_deg(invert(truth) @ alignment.transform) < 1.0
