"""Two-image matching (brute force, threshold, RANSAC) and PnP on scenes with known answers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.geometry import invert
from slamfront.core.pnp import backproject, pnp_ransac
from slamfront.errors import PluginError
from slamfront.imageio import read_image
from slamfront.local_features import LocalFeatureExtractor
from slamfront.matching import DEFAULT_MAX_DISTANCE, Matcher, MatchingConfig, resolve_max_distance

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])


def _project(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    camera = points @ transform[:3, :3].T + transform[:3, 3]
    pixels = camera @ K.T
    return pixels[:, :2] / pixels[:, 2:]


def _scene(seed: int = 0, n: int = 150, n_outliers: int = 60):
    """Points seen by camera A (identity) and camera B, binary descriptors with a few flipped bits."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(4, 10, n)])
    b_from_a = np.eye(4)
    b_from_a[:3, :3] = Rotation.from_rotvec([0.02, -0.1, 0.01]).as_matrix()
    b_from_a[:3, 3] = [-0.5, 0.05, 0.1]
    descriptors = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    noisy = descriptors ^ (rng.random((n, 32 * 8)) < 0.04).reshape(n, 32, 8).dot(1 << np.arange(8)).astype(np.uint8)
    outliers = rng.integers(0, 256, (n_outliers, 32), dtype=np.uint8)
    keypoints_a = _project(points, np.eye(4)).astype(np.float32)
    keypoints_b = np.vstack([_project(points, b_from_a), rng.uniform(0, 320, (n_outliers, 2))]).astype(np.float32)
    return points, b_from_a, (keypoints_a, descriptors), (keypoints_b, np.vstack([noisy, outliers]))


def test_brute_force_threshold_and_ransac_keep_the_true_matches() -> None:
    _, _, (ka, da), (kb, db) = _scene()
    match = Matcher(MatchingConfig(), "hamming", 64).match(ka, da, kb, db)
    correct = match.pairs[:, 0] == match.pairs[:, 1]
    assert match.inliers >= 140 and correct.all()
    assert match.model is not None and match.n_putative >= match.inliers
    assert np.all(match.distances <= 64)
    # a distance threshold below the noise keeps almost nothing
    assert Matcher(MatchingConfig(), "hamming", 2).match(ka, da, kb, db).inliers < 10


@pytest.mark.parametrize(
    "config", [MatchingConfig(ratio=0.8), MatchingConfig(cross_check=True), MatchingConfig(geometry="none"),
               MatchingConfig(ratio=0.8, cross_check=True)],
    ids=["ratio", "cross-check", "no-ransac", "ratio+cross-check"],
)
def test_matching_options(config: MatchingConfig) -> None:
    _, _, (ka, da), (kb, db) = _scene(1)
    match = Matcher(config, "hamming", 64).match(ka, da, kb, db)
    assert match.inliers >= 140
    assert np.mean(match.pairs[:, 0] == match.pairs[:, 1]) > 0.95


def test_random_images_match_little_and_empty_ones_not_at_all() -> None:
    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    points = rng.uniform(0, 320, (300, 2)).astype(np.float32)
    matcher = Matcher(MatchingConfig(), "hamming", DEFAULT_MAX_DISTANCE["orb"])
    assert matcher.match(points, a, points[::-1], b).inliers < 15
    empty = np.zeros((0, 32), np.uint8)
    assert matcher.match(points[:0], empty, points, b).inliers == 0


def test_thresholds_come_from_the_descriptor_type() -> None:
    assert resolve_max_distance(MatchingConfig(), "orb") == DEFAULT_MAX_DISTANCE["orb"]
    assert resolve_max_distance(MatchingConfig(max_distance=7), "orb") == 7
    with pytest.raises(PluginError, match="no default match distance for descriptor 'surf'"):
        resolve_max_distance(MatchingConfig(), "surf")
    with pytest.raises(PluginError, match="l2 or hamming"):
        Matcher(MatchingConfig(), "cosine", 1.0)


def test_revisit_in_real_images_has_the_most_inliers(shared_data: Path) -> None:
    """images/loop10: 10.png comes back to the desk of 1.png; 5.png is elsewhere."""
    extractor = LocalFeatureExtractor("orb", max_features=1000)
    first, revisit, elsewhere = (
        extractor.extract(read_image(shared_data / f"images/loop10/{i}.png", "gray")) for i in (1, 10, 5)
    )
    matcher = Matcher(MatchingConfig(), "hamming", DEFAULT_MAX_DISTANCE["orb"])
    same = matcher.match(first.keypoints, first.descriptors, revisit.keypoints, revisit.descriptors).inliers
    other = matcher.match(first.keypoints, first.descriptors, elsewhere.keypoints, elsewhere.descriptors).inliers
    assert same > 100 and same > 4 * other


def test_pnp_recovers_the_pose_despite_outliers() -> None:
    points, b_from_a, _, (kb, _) = _scene(4, n_outliers=0)
    image = kb.copy()
    image[:40] = np.random.default_rng(5).uniform(0, 320, (40, 2))  # 40 of 150 wrong
    result = pnp_ransac(points, image, K, threshold_px=2.0)
    assert result is not None
    np.testing.assert_allclose(result.transform, b_from_a, atol=1e-6)
    assert set(result.inliers.tolist()) == set(range(40, 150)) and result.reprojection_error_px < 1e-3
    assert pnp_ransac(points[:10], image[:10], K) is None  # fewer than min_inliers
    unknown = points.copy()
    unknown[40:] = np.nan  # no depth where the matches are right
    assert pnp_ransac(unknown, image, K) is None


def test_backprojection_skips_depth_edges_and_holes() -> None:
    depth = np.full((40, 60), 2.0, np.float32)
    depth[:, 30:] = 5.0  # a step at column 30
    depth[5, 5] = 0.0  # a hole
    keypoints = np.array([[10.0, 20.0], [29.6, 20.0], [45.0, 10.0], [5.0, 5.0], [70.0, 5.0]])
    points = backproject(keypoints, depth, K)
    assert points[0] == pytest.approx([(10 - 160) / 300 * 2, (20 - 120) / 300 * 2, 2.0])
    assert np.isnan(points[1]).all()  # next to the step: ambiguous depth
    assert points[2][2] == pytest.approx(5.0)
    assert np.isnan(points[3]).all() and np.isnan(points[4]).all()  # hole; outside the image
    assert not np.isnan(backproject(keypoints[1:2], depth, K, max_relative_spread=None)).any()


def test_pnp_pose_composes_into_a_world_pose() -> None:
    """The localizer's rule: T_world_frame = T_world_keyframe @ inv(T_frame_keyframe)."""
    points, b_from_a, _, (kb, _) = _scene(6, n_outliers=0)
    world_from_a = np.eye(4)
    world_from_a[:3, 3] = [10.0, 0.0, 2.0]
    result = pnp_ransac(points, kb, K)
    np.testing.assert_allclose(world_from_a @ invert(result.transform), world_from_a @ invert(b_from_a), atol=1e-6)


def test_pnp_on_many_to_one_correspondences_keeps_the_first_of_each() -> None:
    """Nearest-neighbour matching is many-to-one: several pixels for one 3-D point. PnP keeps
    the first (give them closest first) and still finds the pose; never raises."""
    points, b_from_a, _, (kb, _) = _scene(7, n_outliers=0)
    rng = np.random.default_rng(8)
    repeats = rng.integers(0, 20, 60)  # 60 more rows, each a wrong pixel for one of the first 20 points
    objects = np.concatenate([points, points[repeats]])
    pixels = np.concatenate([kb, rng.uniform(0, 320, (60, 2))])
    result = pnp_ransac(objects, pixels, K, threshold_px=2.0)
    assert result is not None
    np.testing.assert_allclose(result.transform, b_from_a, atol=1e-6)
    assert result.inliers.max() < len(points)  # the repeated rows were never used


@pytest.mark.parametrize("case", ["three_points_28_rows", "one_point", "collinear", "coincident", "nan_pixels"])
def test_pnp_on_degenerate_input_is_a_failure_not_an_error(case: str) -> None:
    """SQPnP asserts (cv2.error) on correspondences carrying few distinct points, as
    many-to-one matching gives; these and their relatives are None, never an exception."""
    rng = np.random.default_rng(0)
    objects = np.column_stack([rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3), rng.uniform(4, 6, 3)])
    if case == "three_points_28_rows":  # raised cv2.error before the rows were made one-to-one
        rows = rng.integers(0, 3, 28)
        objects, pixels = objects[rows], _project(objects[rows], np.eye(4)) + rng.normal(0, 1, (28, 2))
    elif case == "one_point":
        objects, pixels = np.repeat(objects[:1], 30, axis=0), rng.uniform(0, 320, (30, 2))
    elif case == "collinear":
        objects = np.column_stack([np.linspace(-1, 1, 30), np.zeros(30), np.full(30, 5.0)])
        pixels = _project(objects, np.eye(4))
    elif case == "coincident":
        objects = np.array([1.0, 0.5, 5.0]) + rng.normal(0, 1e-9, (30, 3))
        pixels = rng.uniform(0, 320, (30, 2))
    else:
        objects = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30), rng.uniform(4, 6, 30)])
        pixels = np.full((30, 2), np.nan)
    result = pnp_ransac(objects, pixels, K, min_inliers=4)
    assert result is None or np.all(np.isfinite(result.transform))
    if case in ("one_point", "nan_pixels"):
        assert result is None
