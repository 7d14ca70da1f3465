"""Trajectory metrics: Umeyama alignment, ATE and RPE by hand, and agreement with evo on real data."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.alignment import ate_rmse, umeyama
from slamfront.core.errors import CoreError
from slamfront.core.trajectory import (
    absolute_trajectory_error,
    all_intervals_error,
    associate,
    delta_pairs,
    evaluate_poses,
    evaluate_trajectories,
    relative_pose_error,
)
from slamfront.formats.poses import read_tum


def _poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, (n, 3))).as_matrix()
    poses[:, :3, 3] = np.cumsum(rng.normal(0, 0.3, (n, 3)), axis=0)
    return poses


@pytest.mark.parametrize("d", [2, 3])
def test_umeyama_recovers_a_similarity(d: int) -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(30, d))
    angle = 0.7
    rotation = Rotation.from_rotvec([0.3, -0.2, angle]).as_matrix() if d == 3 else np.array(
        [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    )
    dst = 2.5 * src @ rotation.T + np.arange(1, d + 1)
    r, t, s = umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(r, rotation, atol=1e-12)
    np.testing.assert_allclose(t, np.arange(1, d + 1), atol=1e-12)
    assert s == pytest.approx(2.5)
    r, t, s = umeyama(src, dst)  # rigid: scale stays 1
    assert s == 1.0 and np.linalg.det(r) == pytest.approx(1.0)


def test_umeyama_never_returns_a_reflection() -> None:
    src = np.random.default_rng(2).normal(size=(20, 3))
    mirrored = src * np.array([1.0, 1.0, -1.0])
    rotation, _, _ = umeyama(src, mirrored)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_umeyama_rejects_bad_input() -> None:
    with pytest.raises(CoreError, match="at least 2"):
        umeyama(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(CoreError, match="coincide"):
        umeyama(np.ones((5, 3)), np.zeros((5, 3)))
    with pytest.raises(CoreError, match="one shape"):
        umeyama(np.zeros((5, 3)), np.zeros((4, 3)))


def test_ate_is_zero_for_a_moved_copy_and_the_move_without_alignment() -> None:
    gt = _poses(40)
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_rotvec([0.1, 0.4, -0.3]).as_matrix()
    motion[:3, 3] = [3.0, -1.0, 0.5]
    est = motion @ gt
    assert absolute_trajectory_error(gt, est, "se3").statistics.rmse == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse(est[:, :3, 3], gt[:, :3, 3]) == pytest.approx(0.0, abs=1e-9)
    unaligned = absolute_trajectory_error(gt, est, "none")
    np.testing.assert_allclose(unaligned.errors, np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1))
    scaled = est.copy()
    scaled[:, :3, 3] *= 3.0
    assert absolute_trajectory_error(gt, scaled, "se3").statistics.rmse > 0.1
    sim3 = absolute_trajectory_error(gt, scaled, "sim3")
    assert sim3.statistics.rmse == pytest.approx(0.0, abs=1e-9) and sim3.alignment.scale == pytest.approx(1 / 3)


def test_rpe_by_hand() -> None:
    gt = np.tile(np.eye(4), (4, 1, 1))
    gt[:, 0, 3] = [0.0, 1.0, 2.0, 3.0]  # 1 m steps along x
    est = gt.copy()
    est[2:, 0, 3] += 0.5  # one step 0.5 m too long
    result = relative_pose_error(gt, est, delta_pairs(np.arange(4.0), 1))
    np.testing.assert_allclose(result.translation, [0.0, 0.5, 0.0])
    assert result.translation_statistics.rmse == pytest.approx(np.sqrt(0.25 / 3))
    two = relative_pose_error(gt, est, delta_pairs(np.arange(4.0), 2))
    np.testing.assert_allclose(two.translation, [0.5, 0.5])


def test_delta_pairs_in_frames_and_seconds() -> None:
    assert delta_pairs(np.arange(5.0), 2).tolist() == [[0, 2], [1, 3], [2, 4]]
    stamps = np.array([0.0, 0.1, 0.21, 0.3, 0.42, 0.5])
    # 0.2 s later: the closest pose, as long as it lies within the trajectory
    assert delta_pairs(stamps, 0.2, "seconds").tolist() == [[0, 2], [1, 3], [2, 4], [3, 5]]
    with pytest.raises(CoreError, match="whole number"):
        delta_pairs(stamps, 1.5, "frames")
    with pytest.raises(CoreError, match="positive"):
        delta_pairs(stamps, 0, "frames")


def test_association_that_finds_nothing_says_so() -> None:
    with pytest.raises(CoreError, match="no timestamps could be associated"):
        evaluate_trajectories(np.arange(5.0), _poses(5), np.arange(5.0) + 100, _poses(5))


@pytest.fixture(scope="module")
def fr1(shared_data: Path) -> tuple[Path, Path]:
    folder = shared_data / "trajectories/fr1_gt_vs_est"
    return folder / "groundtruth.txt", folder / "estimated.txt"


def test_agrees_with_evo_on_the_shared_trajectory_pair(fr1: tuple[Path, Path]) -> None:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    gt_path, est_path = fr1
    evo_gt, evo_est = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(gt_path)),
        file_interface.read_tum_trajectory_file(str(est_path)),
        max_diff=0.01,
    )
    gt, est = read_tum(gt_path), read_tum(est_path)
    pairs = associate(gt.timestamps, est.timestamps, 0.01)
    np.testing.assert_array_equal(gt.timestamps[pairs[:, 0]], evo_gt.timestamps)  # the same association
    np.testing.assert_array_equal(est.timestamps[pairs[:, 1]], evo_est.timestamps)

    for align, correct_scale in (("se3", False), ("sim3", True)):
        aligned = copy.deepcopy(evo_est)
        aligned.align(evo_gt, correct_scale=correct_scale)
        ours = evaluate_trajectories(gt.timestamps, gt.poses, est.timestamps, est.poses, 0.01, method=align)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((evo_gt, aligned))
        theirs = ape.get_all_statistics()
        stats = ours.ate.statistics
        for key in ("rmse", "mean", "median", "std", "min", "max", "sse"):
            assert getattr(stats, key) == pytest.approx(theirs[key], abs=1e-6), (align, key)
        for delta in (1, 5):
            ours = evaluate_trajectories(gt.timestamps, gt.poses, est.timestamps, est.poses, 0.01, method=align,
                                         delta=delta)
            for relation, mine in (
                (metrics.PoseRelation.translation_part, ours.rpe.translation_statistics),
                (metrics.PoseRelation.rotation_angle_deg, ours.rpe.rotation_statistics),
            ):
                rpe = metrics.RPE(relation, delta=delta, delta_unit=metrics.Unit.frames, all_pairs=True)
                rpe.process_data((evo_gt, aligned))
                theirs = rpe.get_all_statistics()
                for key in ("rmse", "mean", "median", "max"):
                    assert getattr(mine, key) == pytest.approx(theirs[key], abs=1e-6), (align, delta, relation, key)
    assert ours.metrics()["ate_rmse_m"] == pytest.approx(0.0226010, abs=1e-6)  # sim3, as evo_ape -as prints


def test_evaluate_poses_needs_three_for_alignment() -> None:
    with pytest.raises(CoreError, match="at least 3"):
        evaluate_poses(_poses(2), _poses(2))


def test_all_intervals_rpe_is_the_mean_of_every_intervals_rmse() -> None:
    """Sturm et al. 2012: RMSE(E_1:n) = mean over delta of RMSE(E_1:n, delta), all N (N-1)/2 pairs used."""
    rng = np.random.default_rng(3)
    gt = _poses(12)
    est = gt.copy()
    est[:, :3, 3] += rng.normal(0, 0.05, (12, 3))
    every = all_intervals_error(gt, est)
    per_delta = [relative_pose_error(gt, est, delta_pairs(np.arange(12.0), d)) for d in range(1, 12)]
    assert every.rmse == pytest.approx(np.mean([r.translation_statistics.rmse for r in per_delta]), rel=1e-12)
    assert every.max == pytest.approx(max(r.translation_statistics.max for r in per_delta), rel=1e-12)
    assert every.n_pairs == 66
    assert np.isnan(all_intervals_error(gt[:1], est[:1]).rmse)


def test_all_intervals_rpe_agrees_with_evo_delta_by_delta(fr1: tuple[Path, Path]) -> None:
    """What `evo_rpe tum GT EST -a --delta d --all_pairs` gives for every d, averaged (first 80 poses)."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    evo_gt, evo_est = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(fr1[0])), file_interface.read_tum_trajectory_file(str(fr1[1])))
    evo_gt.reduce_to_ids(range(80))
    evo_est.reduce_to_ids(range(80))
    evo_est.align(evo_gt)
    theirs = []
    for delta in range(1, 80):
        rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=delta, delta_unit=metrics.Unit.frames,
                          all_pairs=True)
        rpe.process_data((evo_gt, evo_est))
        theirs.append(rpe.get_statistic(metrics.StatisticsType.rmse))
    ours = evaluate_poses(evo_gt.poses_se3, evo_est.poses_se3, method="none", all_intervals=True)
    assert ours.metrics()["rpe_all_intervals_rmse_m"] == pytest.approx(np.mean(theirs), abs=1e-9)


def test_quaternion_conversions_are_scipys_bits() -> None:
    from scipy.spatial.transform import Rotation

    from slamfront.core import geometry

    rng = np.random.default_rng(7)
    quaternions = rng.standard_normal((5000, 4))
    quaternions[:10] = [[0, 0, 0, 1], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, -1],
                        [0.5, 0.5, 0.5, 0.5], [0, 0, 1e-9, 1], [1, 1, 0, 0], [0, 0, 1, 1], [1e-3, 0, 0, -1]]
    matrices = geometry.quaternion_matrices(quaternions)
    assert matrices.tobytes() == Rotation.from_quat(quaternions).as_matrix().tobytes()
    perturbed = matrices + rng.normal(0, 1e-13, matrices.shape)  # orthonormal to rounding, as an optimiser leaves them
    skewed = matrices + rng.normal(0, 1e-9, matrices.shape)  # SciPy re-orthogonalises these first
    for m in (matrices, perturbed, skewed):
        assert geometry.matrix_quaternions(m).tobytes() == Rotation.from_matrix(m).as_quat().tobytes()
