"""Trajectory metrics of Sturm et al. 2012 (TUM RGB-D benchmark), on arrays.

- **ATE** (absolute trajectory error, eqs. 4.4-4.5 of Barbosa 2017): align the estimate to
  the ground truth (Horn/Umeyama, rigid or with scale), then ``F_i = Q_i^-1 S P_i``;
  statistics of ``|trans F_i|``.
- **RPE** (relative pose error, eqs. 4.2-4.3): ``E_i = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` for
  every pair ``(i, j)`` a fixed delta apart (frames or seconds); statistics of
  ``|trans E_i|`` and of the rotation angle of ``E_i``. Over all intervals (Sturm et al.
  2012, what Barbosa 2017's table 6 reports): the mean over every delta of that delta's
  RMSE (:func:`all_intervals_error`).
- **Association** of two timestamped trajectories as the benchmark's ``associate.py``.

Poses are (N, 4, 4) camera-to-world transforms; ``Q`` is the ground truth, ``P`` the
estimate. Nothing here reads files: :mod:`slamfront.formats.poses` does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from slamfront.core.alignment import umeyama
from slamfront.core.errors import CoreError

AlignMethod = Literal["se3", "sim3", "none"]
DeltaUnit = Literal["frames", "seconds"]


def associate(first: np.ndarray, second: np.ndarray, max_difference: float = 0.02, offset: float = 0.0) -> np.ndarray:
    """(K, 2) index pairs (i, j) with ``|first[i] - (second[j] + offset)| < max_difference``.

    Greedy and one-to-one, closest pairs first, sorted by ``i`` (the TUM benchmark's
    ``associate.py``).
    """
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64) + offset
    order = np.argsort(second)
    sorted_second = second[order]
    candidates = []
    for i, stamp in enumerate(first):
        lo = np.searchsorted(sorted_second, stamp - max_difference, side="left")
        hi = np.searchsorted(sorted_second, stamp + max_difference, side="right")
        for k in range(lo, hi):
            difference = abs(stamp - sorted_second[k])
            if difference < max_difference:
                candidates.append((difference, i, int(order[k])))
    candidates.sort()
    used_first, used_second, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    pairs.sort()
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


@dataclass(frozen=True)
class ErrorStatistics:
    """Summary of non-negative errors (metres or degrees)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def of(cls, errors: np.ndarray) -> ErrorStatistics:
        """Statistics of (N,) errors; all NaN when N = 0."""
        errors = np.asarray(errors, dtype=np.float64)
        if len(errors) == 0:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, nan, 0)
        squared = errors**2
        return cls(
            rmse=float(np.sqrt(squared.mean())),
            mean=float(errors.mean()),
            median=float(np.median(errors)),
            std=float(errors.std()),
            min=float(errors.min()),
            max=float(errors.max()),
            sse=float(squared.sum()),
            n=len(errors),
        )


@dataclass(frozen=True)
class Alignment:
    """The similarity ``S: p -> s R p + t`` that maps the estimate onto the ground truth."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0

    def apply_to_poses(self, poses: np.ndarray) -> np.ndarray:
        """(N, 4, 4) poses ``S P``: rotations turned by ``R``, positions mapped by ``S`` (new array)."""
        out = np.array(poses, dtype=np.float64, copy=True)
        out[:, :3, :3] = self.rotation @ out[:, :3, :3]
        out[:, :3, 3] = self.scale * out[:, :3, 3] @ self.rotation.T + self.translation
        return out


IDENTITY = Alignment(np.eye(3), np.zeros(3), 1.0)


def align(gt_poses: np.ndarray, est_poses: np.ndarray, method: AlignMethod = "se3") -> Alignment:
    """Align the estimated positions onto the ground-truth ones (Horn/Umeyama).

    :param method: ``se3`` (rigid, the benchmark's choice), ``sim3`` (also scale, for
        monocular estimates) or ``none``.
    """
    if method == "none":
        return IDENTITY
    rotation, translation, scale = umeyama(est_poses[:, :3, 3], gt_poses[:, :3, 3], with_scale=method == "sim3")
    return Alignment(rotation, translation, scale)


def _rotation_angles_deg(rotations: np.ndarray) -> np.ndarray:
    cosine = (np.trace(rotations, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def _check_pair(gt_poses: np.ndarray, est_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gt = np.asarray(gt_poses, dtype=np.float64)
    est = np.asarray(est_poses, dtype=np.float64)
    if gt.ndim != 3 or gt.shape[1:] != (4, 4) or gt.shape != est.shape:
        raise CoreError(f"need two (N, 4, 4) pose arrays of one shape, got {gt.shape} and {est.shape}")
    return gt, est


@dataclass(frozen=True)
class AbsoluteError:
    """ATE of associated poses.

    :ivar errors: (N,) ``|trans F_i|`` in metres.
    :ivar rotation_errors_deg: (N,) rotation angle of ``F_i``.
    """

    errors: np.ndarray
    rotation_errors_deg: np.ndarray
    statistics: ErrorStatistics
    alignment: Alignment


def absolute_trajectory_error(gt_poses: np.ndarray, est_poses: np.ndarray, method: AlignMethod = "se3") -> AbsoluteError:
    """ATE (eqs. 4.4-4.5) of (N, 4, 4) associated poses, after alignment by ``method``."""
    gt, est = _check_pair(gt_poses, est_poses)
    if method != "none" and len(gt) < 3:
        raise CoreError(f"aligning trajectories needs at least 3 associated poses, got {len(gt)}")
    alignment = align(gt, est, method)
    aligned = alignment.apply_to_poses(est)
    # |trans(Q^-1 S P)| = |R_Q^T (t_SP - t_Q)| = |t_SP - t_Q|
    errors = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    rotation = np.transpose(gt[:, :3, :3], (0, 2, 1)) @ aligned[:, :3, :3]
    return AbsoluteError(errors, _rotation_angles_deg(rotation), ErrorStatistics.of(errors), alignment)


def delta_pairs(timestamps: np.ndarray, delta: float, unit: DeltaUnit = "frames") -> np.ndarray:
    """(M, 2) index pairs ``(i, j)`` that are ``delta`` apart, for every ``i`` (eq. 4.3's m = n - delta).

    ``frames``: ``j = i + delta``. ``seconds``: ``j`` is the pose closest in time to
    ``t_i + delta``; pairs whose target lies beyond the last pose by more than half the
    median frame interval are dropped (the benchmark's tool would pair them with the
    last pose, a shorter interval).
    """
    stamps = np.asarray(timestamps, dtype=np.float64)
    n = len(stamps)
    if delta <= 0:
        raise CoreError(f"the RPE delta must be positive, got {delta}")
    if unit == "frames":
        step = int(delta)
        if step != delta:
            raise CoreError(f"a delta in frames must be a whole number, got {delta}")
        first = np.arange(max(n - step, 0), dtype=np.int64)
        return np.stack([first, first + step], axis=1)
    if n > 1 and np.any(np.diff(stamps) <= 0):
        raise CoreError("a delta in seconds needs strictly increasing timestamps")
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    slack = 0.5 * float(np.median(np.diff(stamps)))
    targets = stamps + delta
    right = np.clip(np.searchsorted(stamps, targets), 1, n - 1)
    left = right - 1
    closest = np.where(np.abs(stamps[left] - targets) <= np.abs(stamps[right] - targets), left, right)
    keep = (targets <= stamps[-1] + slack) & (closest > np.arange(n))
    return np.stack([np.arange(n)[keep], closest[keep]], axis=1).astype(np.int64)


@dataclass(frozen=True)
class RelativeError:
    """RPE over index pairs.

    :ivar pairs: (M, 2) the ``(i, j)`` each error is about.
    :ivar translation: (M,) ``|trans E_i|`` in metres.
    :ivar rotation_deg: (M,) rotation angle of ``E_i``.
    """

    pairs: np.ndarray
    translation: np.ndarray
    rotation_deg: np.ndarray
    translation_statistics: ErrorStatistics
    rotation_statistics: ErrorStatistics


def relative_pose_error(gt_poses: np.ndarray, est_poses: np.ndarray, pairs: np.ndarray) -> RelativeError:
    """RPE (eqs. 4.2-4.3) of (N, 4, 4) associated poses over (M, 2) index ``pairs``."""
    gt, est = _check_pair(gt_poses, est_poses)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) and (pairs.min() < 0 or pairs.max() >= len(gt)):
        raise CoreError(f"RPE pairs index outside the {len(gt)} poses")
    i, j = pairs[:, 0], pairs[:, 1]
    motion_gt = _inverse(gt[i]) @ gt[j]
    motion_est = _inverse(est[i]) @ est[j]
    error = _inverse(motion_gt) @ motion_est
    translation = np.linalg.norm(error[:, :3, 3], axis=1)
    rotation = _rotation_angles_deg(error[:, :3, :3])
    return RelativeError(pairs, translation, rotation, ErrorStatistics.of(translation), ErrorStatistics.of(rotation))


@dataclass(frozen=True)
class AllIntervalsError:
    """RPE over every time interval of a trajectory (Sturm et al. 2012).

    :ivar rmse: ``1/(n-1) sum_{delta=1}^{n-1} RMSE(E, delta)``: the mean over intervals of
        each interval's translational RMSE, metres (the benchmark paper's definition).
    :ivar max: largest ``|trans E|`` over all pairs ``i < j``, metres.
    :ivar rotation_rmse_deg: the same mean of per-interval RMSEs for the rotation angle.
    :ivar n_pairs: pairs evaluated, ``n (n - 1) / 2``.
    """

    rmse: float
    max: float
    rotation_rmse_deg: float
    n_pairs: int


def all_intervals_error(gt_poses: np.ndarray, est_poses: np.ndarray) -> AllIntervalsError:
    """RPE of (N, 4, 4) associated poses over every interval ``delta = 1 .. N-1`` (in index order).

    One interval at a time, so memory stays O(N) although all N (N - 1) / 2 pairs are used.
    """
    gt, est = _check_pair(gt_poses, est_poses)
    n = len(gt)
    if n < 2:
        nan = float("nan")
        return AllIntervalsError(nan, nan, nan, 0)
    gt_inverse, est_inverse = _inverse(gt), _inverse(est)
    rmse, rotation_rmse, largest = [], [], 0.0
    for delta in range(1, n):
        error = _inverse(gt_inverse[:-delta] @ gt[delta:]) @ (est_inverse[:-delta] @ est[delta:])
        translation = np.linalg.norm(error[:, :3, 3], axis=1)
        rotation = _rotation_angles_deg(error[:, :3, :3])
        rmse.append(np.sqrt(np.mean(translation**2)))
        rotation_rmse.append(np.sqrt(np.mean(rotation**2)))
        largest = max(largest, float(translation.max()))
    return AllIntervalsError(float(np.mean(rmse)), largest, float(np.mean(rotation_rmse)), n * (n - 1) // 2)


@dataclass(frozen=True)
class Drift:
    """How far an estimate has drifted by its last pose.

    :ivar translation_m: position error of the last pose relative to the first (the
        translation of the RPE over the pair first -> last): the gap the estimate leaves
        where the truth closes a loop.
    :ivar rotation_deg: the same for the orientation.
    :ivar path_length_m: distance travelled along the ground truth.
    """

    translation_m: float
    rotation_deg: float
    path_length_m: float

    @property
    def percent(self) -> float:
        """``translation_m`` per 100 m travelled (NaN for a standing camera)."""
        return 100.0 * self.translation_m / self.path_length_m if self.path_length_m > 0 else float("nan")


def end_drift(gt_poses: np.ndarray, est_poses: np.ndarray) -> Drift:
    """Drift of (N, 4, 4) estimated poses against their associated ground truth, N >= 2.

    Independent of any alignment: only the motion from the first to the last pose counts.
    """
    gt, est = _check_pair(gt_poses, est_poses)
    if len(gt) < 2:
        raise CoreError(f"drift needs at least 2 poses, got {len(gt)}")
    error = relative_pose_error(gt, est, np.array([[0, len(gt) - 1]]))
    length = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
    return Drift(float(error.translation[0]), float(error.rotation_deg[0]), length)


def _inverse(poses: np.ndarray) -> np.ndarray:
    """Inverse of rigid (N, 4, 4) transforms (R^T rather than a general inverse)."""
    transposed = np.transpose(poses[:, :3, :3], (0, 2, 1))
    out = np.zeros_like(poses)
    out[:, :3, :3] = transposed
    out[:, :3, 3] = -(transposed @ poses[:, :3, 3, None])[:, :, 0]
    out[:, 3, 3] = 1.0
    return out


@dataclass(frozen=True)
class TrajectoryEvaluation:
    """ATE and RPE of an estimate against the ground truth.

    :ivar pairs: (K, 2) associated indices (ground truth, estimate).
    """

    pairs: np.ndarray
    ate: AbsoluteError
    rpe: RelativeError
    align: AlignMethod
    delta: float
    delta_unit: DeltaUnit
    all_intervals: AllIntervalsError | None = None

    def metrics(self) -> dict[str, float | int | str]:
        """Flat metrics, metres and degrees, as ``metrics.json`` and ``eval traj --json`` give them."""
        a, t, r = self.ate.statistics, self.rpe.translation_statistics, self.rpe.rotation_statistics
        every = {} if self.all_intervals is None else {
            "rpe_all_intervals_rmse_m": self.all_intervals.rmse,
            "rpe_all_intervals_max_m": self.all_intervals.max,
            "rpe_all_intervals_rotation_rmse_deg": self.all_intervals.rotation_rmse_deg,
        }
        return {
            "ate_rmse_m": a.rmse,
            "ate_mean_m": a.mean,
            "ate_median_m": a.median,
            "ate_std_m": a.std,
            "ate_min_m": a.min,
            "ate_max_m": a.max,
            "rpe_rmse_m": t.rmse,
            "rpe_mean_m": t.mean,
            "rpe_median_m": t.median,
            "rpe_max_m": t.max,
            "rpe_rotation_rmse_deg": r.rmse,
            "rpe_rotation_max_deg": r.max,
            "n_associated": int(len(self.pairs)),
            "n_rpe_pairs": t.n,
            "alignment": self.align,
            "alignment_scale": self.ate.alignment.scale,
            "rpe_delta": self.delta,
            "rpe_delta_unit": self.delta_unit,
            **every,
        }


def evaluate_poses(
    gt_poses: np.ndarray,
    est_poses: np.ndarray,
    timestamps: np.ndarray | None = None,
    method: AlignMethod = "se3",
    delta: float = 1,
    delta_unit: DeltaUnit = "frames",
    pairs: np.ndarray | None = None,
    all_intervals: bool = False,
) -> TrajectoryEvaluation:
    """ATE and RPE of already associated (N, 4, 4) poses, in the order given (time order).

    :param timestamps: (N,) seconds, for a delta in seconds (and the record).
    :param pairs: the (N, 2) association these poses came from (default: identity).
    :param all_intervals: also the RPE over every interval (:func:`all_intervals_error`).
    """
    gt, est = _check_pair(gt_poses, est_poses)
    if len(gt) == 0:
        raise CoreError("no associated poses to evaluate")
    ate = absolute_trajectory_error(gt, est, method)
    stamps = np.arange(len(gt), dtype=np.float64) if timestamps is None else np.asarray(timestamps, np.float64)
    if delta_unit == "seconds" and timestamps is None:
        raise CoreError("a delta in seconds needs timestamps")
    rpe_pairs = delta_pairs(stamps, delta, delta_unit)
    # a rigid alignment leaves relative motions unchanged; a scale does not
    aligned = ate.alignment.apply_to_poses(est)
    rpe = relative_pose_error(gt, aligned, rpe_pairs)
    every = all_intervals_error(gt, aligned) if all_intervals else None
    association = np.stack([np.arange(len(gt))] * 2, axis=1) if pairs is None else np.asarray(pairs, np.int64)
    return TrajectoryEvaluation(association, ate, rpe, method, delta, delta_unit, every)


def evaluate_trajectories(
    gt_stamps: np.ndarray,
    gt_poses: np.ndarray,
    est_stamps: np.ndarray,
    est_poses: np.ndarray,
    max_difference: float = 0.01,
    offset: float = 0.0,
    method: AlignMethod = "se3",
    delta: float = 1,
    delta_unit: DeltaUnit = "frames",
    all_intervals: bool = False,
) -> TrajectoryEvaluation:
    """Associate two timestamped trajectories (estimate shifted by ``offset``), then ATE and RPE.

    ``max_difference`` defaults to evo's association window (0.01 s); the TUM
    benchmark's ``associate.py`` uses 0.02 s.

    :raises CoreError: no pose of the estimate is within ``max_difference`` s of one of
        the ground truth.
    """
    pairs = associate(gt_stamps, est_stamps, max_difference, offset)
    if len(pairs) == 0:
        raise CoreError(
            f"no timestamps could be associated: none of the {len(est_stamps)} estimated poses is within "
            f"{max_difference} s of one of the {len(gt_stamps)} ground-truth poses"
        )
    gt = np.asarray(gt_poses, dtype=np.float64)[pairs[:, 0]]
    est = np.asarray(est_poses, dtype=np.float64)[pairs[:, 1]]
    stamps = np.asarray(gt_stamps, dtype=np.float64)[pairs[:, 0]]
    return evaluate_poses(gt, est, stamps, method, delta, delta_unit, pairs, all_intervals)
