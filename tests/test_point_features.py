"""PFH (core.point_features) against slow references, and its neighbourhoods against Open3D's."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.errors import CoreError
from slamfront.core.point_features import PFH_BINS, hybrid_neighbours, pair_features, pfh

# -- slow references, written from PCL's and Open3D's C++ loop by loop --------------------


def _pair_reference(p1, n1, p2, n2) -> tuple[float, float, float, float]:
    """pcl::computePairFeatures, one pair, plain Python floats."""
    dp = [p2[i] - p1[i] for i in range(3)]
    f4 = math.sqrt(sum(d * d for d in dp))
    if f4 == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    n1c, n2c = list(n1), list(n2)
    angle1 = sum(n1c[i] * dp[i] for i in range(3)) / f4
    angle2 = sum(n2c[i] * dp[i] for i in range(3)) / f4
    if math.acos(min(abs(angle1), 1.0)) > math.acos(min(abs(angle2), 1.0)):
        n1c, n2c = list(n2), list(n1)
        dp = [-d for d in dp]
        f3 = -angle2
    else:
        f3 = angle1
    v = [dp[1] * n1c[2] - dp[2] * n1c[1], dp[2] * n1c[0] - dp[0] * n1c[2], dp[0] * n1c[1] - dp[1] * n1c[0]]
    v_norm = math.sqrt(sum(x * x for x in v))
    if v_norm == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    v = [x / v_norm for x in v]
    w = [n1c[1] * v[2] - n1c[2] * v[1], n1c[2] * v[0] - n1c[0] * v[2], n1c[0] * v[1] - n1c[1] * v[0]]
    f2 = sum(v[i] * n2c[i] for i in range(3))
    f1 = math.atan2(sum(w[i] * n2c[i] for i in range(3)), sum(n1c[i] * n2c[i] for i in range(3)))
    return f1, f2, f3, f4


def _bin(value: float, low: float, width: float, splits: int) -> int:
    return min(max(int(math.floor(splits * (value - low) / width)), 0), splits - 1)


def _pfh_reference(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """pcl::PFHEstimation::computePointPFHSignature for every point (no cache)."""
    out = np.zeros((len(points), 125))
    for row, hood in enumerate(neighbours):
        indices = [int(i) for i in hood if i >= 0]
        if len(indices) < 2:
            continue
        increment = 100.0 / (len(indices) * (len(indices) - 1) / 2)
        for i_idx in range(len(indices)):
            for j_idx in range(i_idx):
                a, b = indices[i_idx], indices[j_idx]
                f1, f2, f3, _ = _pair_reference(points[a].tolist(), normals[a].tolist(), points[b].tolist(), normals[b].tolist())
                index = _bin(f1, -math.pi, 2 * math.pi, 5) + 5 * _bin(f2, -1, 2, 5) + 25 * _bin(f3, -1, 2, 5)
                out[row, index] += increment
    return out


def _fpfh_open3d_style(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Open3D's ComputeSPFHFeature + ComputeFPFHFeature, written with our pair_features."""
    n = len(points)
    spfh = np.zeros((n, 33))
    for i, hood in enumerate(neighbours):
        others = [int(j) for j in hood[1:] if j >= 0]
        if not others:
            continue
        f1, f2, f3, _ = pair_features(points[i][None], normals[i][None], points[others], normals[others])
        increment = 100.0 / len(others)
        for offset, values, low, width in ((0, f1, -np.pi, 2 * np.pi), (11, f2, -1, 2), (22, f3, -1, 2)):
            bins = np.clip(np.floor(11 * (values - low) / width), 0, 10).astype(int)
            np.add.at(spfh[i], offset + bins, increment)
    fpfh = np.zeros((n, 33))
    for i, hood in enumerate(neighbours):
        others = [int(j) for j in hood[1:] if j >= 0]
        if not others:
            continue
        sums = np.zeros(3)
        for j in others:
            distance2 = float(np.sum((points[j] - points[i]) ** 2))
            if distance2 == 0.0:
                continue
            values = spfh[j] / distance2
            sums += values.reshape(3, 11).sum(axis=1)
            fpfh[i] += values
        scale = np.where(sums != 0, 100.0 / np.where(sums != 0, sums, 1), 0.0)
        fpfh[i] = fpfh[i] * np.repeat(scale, 11) + spfh[i]
    return fpfh


# -- fixtures -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bunny(shared_data: Path) -> tuple[np.ndarray, np.ndarray]:
    """A few hundred bunny points with normals (oriented to a viewpoint in front)."""
    cloud = o3d.io.read_point_cloud(str(shared_data / "clouds" / "bunny_res3.ply"))
    cloud = cloud.voxel_down_sample(0.01)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=30))
    cloud.orient_normals_towards_camera_location(np.array([0.0, 0.1, 0.5]))
    return np.asarray(cloud.points), np.asarray(cloud.normals)


# -- tests ----------------------------------------------------------------------------------


def test_pfh_matches_the_slow_reference_on_a_small_cloud(bunny) -> None:
    points, normals = bunny
    assert 150 < len(points) < 800
    neighbours = hybrid_neighbours(points, radius=0.025, max_nn=20)
    assert np.mean(np.sum(neighbours >= 0, axis=1)) > 8  # real neighbourhoods, not singletons
    fast = pfh(points, normals, neighbours)
    slow = _pfh_reference(points, normals, neighbours)
    assert fast.shape == (len(points), PFH_BINS)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)
    full = np.sum(neighbours >= 0, axis=1) >= 2
    np.testing.assert_allclose(fast[full].sum(axis=1), 100.0)
    assert len(np.unique(np.argmax(fast, axis=1))) > 5  # the histograms discriminate


def test_pair_features_reproduce_open3d_fpfh(shared_data: Path) -> None:
    """FPFH built on pair_features equals Open3D's: the Darboux-frame angles are right."""
    cloud = o3d.io.read_point_cloud(str(shared_data / "clouds" / "open3d_feature_pair" / "cloud_bin_0.pcd"))
    cloud = cloud.select_by_index(np.arange(0, len(cloud.points), 6))
    points, normals = np.asarray(cloud.points), np.asarray(cloud.normals)
    radius, max_nn = 0.25, 40
    ours = _fpfh_open3d_style(points, normals, hybrid_neighbours(points, radius, max_nn))
    theirs = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn)
    ).data.T
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_neighbourhoods_are_open3ds_hybrid_search(bunny) -> None:
    points, _ = bunny
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    tree = o3d.geometry.KDTreeFlann(cloud)
    ours = hybrid_neighbours(points, radius=0.02, max_nn=12)
    for i in range(0, len(points), 7):
        _, theirs, _ = tree.search_hybrid_vector_3d(points[i], 0.02, 12)
        assert set(ours[i][ours[i] >= 0].tolist()) == set(theirs), i
        assert ours[i][0] == i


def test_pfh_is_invariant_to_rigid_motion(bunny) -> None:
    points, normals = bunny
    rotation = Rotation.from_euler("xyz", [30, -50, 80], degrees=True).as_matrix()
    moved = points @ rotation.T + np.array([1.0, -2.0, 0.5])
    before = pfh(points, normals, hybrid_neighbours(points, 0.025, 20))
    after = pfh(moved, normals @ rotation.T, hybrid_neighbours(moved, 0.025, 20))
    # a pair on a bin edge may flip with rounding; all but a sliver of the mass agrees
    assert np.abs(before - after).sum() / before.sum() < 1e-3


def test_pair_features_degenerate_pairs_are_zero() -> None:
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    n = np.array([[0.0, 0.0, 1.0]] * 3)
    theta, alpha, phi, distance = pair_features(p, n, q, n)
    assert distance[0] == 0 and theta[0] == alpha[0] == phi[0] == 0  # same point
    assert distance[1] == 0 and theta[1] == 0  # normal along the joining line
    assert distance[2] == 1.0 and phi[2] == 0.0


def test_pfh_edge_cases() -> None:
    points = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    lonely = hybrid_neighbours(points, radius=1.0, max_nn=5)
    assert lonely.shape == (2, 5) and (lonely[:, 1:] == -1).all()
    assert not pfh(points, normals, lonely).any()  # fewer than two neighbours: zeros
    assert pfh(np.empty((0, 3)), np.empty((0, 3)), np.empty((0, 4), dtype=np.int64)).shape == (0, PFH_BINS)
    with pytest.raises(CoreError, match="pfh needs"):
        pfh(points, normals[:1], lonely)
    with pytest.raises(CoreError, match="radius"):
        hybrid_neighbours(points, radius=0.0, max_nn=5)
