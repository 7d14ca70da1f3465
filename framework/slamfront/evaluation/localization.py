"""Localization evaluation: ATE and RPE of the localizer's poses against the ground truth,
how many frames were localized and to the right keyframe region, and how long it took.

The estimate of a frame is its ``PoseEstimate.pose``; its ground truth is the pose the
source gave for the same frame (association by frame index, exact). ATE and RPE use
:mod:`slamfront.core.trajectory`, the functions ``slamfront eval traj`` uses. ATE is
reported after rigid Horn alignment (the benchmark's and the paper's convention) and
without it (keyframe poses are already in the ground-truth frame); when the localizer
refines poses, the keyframe-only ATE of the same frames is reported beside it. RPE is
over consecutive localized frames in arrival order.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from slamfront.core.errors import CoreError
from slamfront.core.trajectory import absolute_trajectory_error, delta_pairs, evaluate_poses, relative_pose_error
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.formats.poses import Trajectory, write_tum
from slamfront.messages import FrameInfo, KeyframeAdded, Message, PoseEstimate
from slamfront.report import plots


class LocalizationEvaluation(Evaluation):
    """Scores every ``PoseEstimate`` against the ground-truth pose of its frame."""

    title = "Localization"

    def __init__(self) -> None:
        self._truth: dict[int, tuple[float, str, int, np.ndarray | None]] = {}
        self._estimates: dict[int, PoseEstimate] = {}
        self._keyframes: dict[int, np.ndarray | None] = {}

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._truth[message.frame] = (message.timestamp, message.traversal, message.sequence_index, message.pose)
        elif isinstance(message, PoseEstimate):
            self._estimates[message.frame] = message
        elif isinstance(message, KeyframeAdded):
            self._keyframes[message.frame] = message.pose

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        if not self._estimates:
            return EvaluationReport(self.title, metrics={"n_keyframes": len(self._keyframes)},
                                    markdown="No frame was localized (no PoseEstimate messages).\n")
        estimates = [self._estimates[f] for f in sorted(self._estimates)]
        localized = [e for e in estimates if e.keyframe >= 0]
        metrics: dict[str, float | int | str | None] = {
            "n_keyframes": len(self._keyframes),
            "n_localization_queries": len(estimates),
            "n_frames_localized": len(localized),
            "n_too_few_features": sum(e.reason.startswith("too few features") for e in estimates),
            "fraction_localized": len(localized) / len(estimates),
            "n_refined": sum(e.refined for e in estimates),
        }
        # a keyframe without a pose (no ground truth for it) localizes topologically only
        scored = [e for e in localized
                  if e.pose is not None and self._truth.get(e.frame, (0, "", 0, None))[3] is not None]
        figures: list[str] = []
        notes = []
        if scored:
            metrics.update(self._trajectory_metrics(scored))
            metrics.update(self._region_metrics(scored))
            self._write_trajectories(context.out_dir, scored)
            if context.options.plots:
                lost = [e for e in estimates if e.keyframe < 0 and self._truth.get(e.frame, (0, "", 0, None))[3] is not None]
                figures = self._plots(context.out_dir, scored, lost)
        else:
            notes.append("No localized frame has a ground-truth pose: no ATE/RPE.")
        reasons = Counter(re.sub(r"\d+", "N", e.reason) for e in estimates if e.keyframe < 0)
        if reasons:
            notes.append("Not localized: " + "; ".join(f"{n} x {why}" for why, n in reasons.most_common()) + ".")
        # the localizer's own timings are already in metrics.json (stage statistics); show them here too
        shown = {**metrics, **{k: v for k, v in context.statistics.items() if k.startswith("localization_latency")}}
        table = "\n".join(["| metric | value |", "| --- | --- |", *(f"| {k} | {_fmt(v)} |" for k, v in shown.items())])
        markdown = "\n\n".join([*notes, table, *(f"![{f}]({f})" for f in figures)]) + "\n"
        if scored:
            markdown += (
                "\nTrajectories in TUM format: `estimated_tum.txt`, `groundtruth_tum.txt` "
                "(`slamfront eval traj groundtruth_tum.txt estimated_tum.txt` gives the same ATE).\n"
            )
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)

    # --- metrics ----------------------------------------------------------------------

    def _arrays(self, scored: list[PoseEstimate]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrival-ordered (timestamps, ground truth, estimates)."""
        stamps = np.array([self._truth[e.frame][0] for e in scored], dtype=np.float64)
        gt = np.stack([self._truth[e.frame][3] for e in scored])
        est = np.stack([e.pose for e in scored])
        return stamps, gt, est

    def _trajectory_metrics(self, scored: list[PoseEstimate]) -> dict[str, float | int | str]:
        stamps, gt, est = self._arrays(scored)
        metrics = _scores(gt, est, stamps)
        if any(e.refined for e in scored):
            keyframe_only = _scores(gt, np.stack([e.keyframe_pose for e in scored]), stamps)
            metrics["ate_rmse_keyframe_pose_m"] = keyframe_only["ate_rmse_m"]
            metrics["rpe_rmse_keyframe_pose_m"] = keyframe_only["rpe_rmse_m"]
            metrics["ate_rmse_keyframe_pose_unaligned_m"] = keyframe_only["ate_rmse_unaligned_m"]
        return metrics

    def _region_metrics(self, scored: list[PoseEstimate]) -> dict[str, float | int]:
        """Was each frame given a keyframe of its own region of the map?

        Correct when the chosen keyframe is no more than two keyframe spacings (the
        median distance between consecutive keyframes) farther from the frame's true
        position than the nearest keyframe: the nearest node or one of its two
        neighbours either way along the route, which see the same scene.
        """
        keyframe_positions = np.array(
            [p[:3, 3] for p in self._keyframes.values() if p is not None], dtype=np.float64
        ).reshape(-1, 3)
        if len(keyframe_positions) == 0:
            return {}
        spacing = float(np.median(np.linalg.norm(np.diff(keyframe_positions, axis=0), axis=1))) if len(
            keyframe_positions
        ) > 1 else 0.0
        correct = 0
        chosen_distance = []
        for e in scored:
            truth = self._truth[e.frame][3][:3, 3]
            nearest = float(np.min(np.linalg.norm(keyframe_positions - truth, axis=1)))
            chosen = float(np.linalg.norm(e.keyframe_pose[:3, 3] - truth))
            chosen_distance.append(chosen)
            correct += chosen <= nearest + 2.0 * spacing + 1e-9
        return {
            "fraction_correct_keyframe_region": correct / len(scored),
            "n_wrong_keyframe_region": len(scored) - correct,
            "keyframe_spacing_m": spacing,
            "keyframe_distance_median_m": float(np.median(chosen_distance)),
            "keyframe_distance_max_m": float(np.max(chosen_distance)),
        }

    # --- outputs ----------------------------------------------------------------------

    def _write_trajectories(self, out_dir: Path, scored: list[PoseEstimate]) -> None:
        stamps, gt, est = self._arrays(scored)
        order = np.argsort(stamps, kind="stable")
        write_tum(out_dir / "estimated_tum.txt", Trajectory(stamps[order], est[order]))
        write_tum(out_dir / "groundtruth_tum.txt", Trajectory(stamps[order], gt[order]))

    def _plots(self, out_dir: Path, scored: list[PoseEstimate], lost: list[PoseEstimate]) -> list[str]:
        """Top view and error along the route; spikes circled, frames not localized marked."""
        # along the route (traversal, then dataset order), so a shuffled run still draws a path
        route = sorted(scored, key=lambda e: (self._truth[e.frame][1], self._truth[e.frame][2]))
        gt = np.stack([self._truth[e.frame][3][:3, 3] for e in route])
        est = np.stack([e.pose[:3, 3] for e in route])
        keyframes = np.array([p[:3, 3] for p in self._keyframes.values() if p is not None]).reshape(-1, 3)
        trajectory = plots.localization_plot(
            gt, est, keyframes, out_dir / "localization.png", "estimated vs ground-truth trajectory",
            lost=np.array([self._truth[e.frame][3][:3, 3] for e in lost]).reshape(-1, 3),
        )
        errors = np.linalg.norm(est - gt, axis=1)
        error = plots.error_along(
            np.array([self._truth[e.frame][2] for e in route], dtype=np.float64), errors,
            out_dir / "localization_error.png", "position error per frame (unaligned)", "sequence index",
            "error [m]", missing=np.array([self._truth[e.frame][2] for e in lost], dtype=np.float64),
        )
        return [trajectory.name, error.name]


def _scores(gt: np.ndarray, est: np.ndarray, stamps: np.ndarray) -> dict[str, float | int | str]:
    """ATE/RPE after rigid alignment, and ATE without; unaligned only when alignment is undetermined."""
    unaligned = absolute_trajectory_error(gt, est, "none").statistics
    try:
        metrics = evaluate_poses(gt, est, stamps, "se3", delta=1, delta_unit="frames").metrics()
    except CoreError as exc:  # fewer than 3 poses, or every estimate at one keyframe
        rpe = relative_pose_error(gt, est, delta_pairs(stamps, 1)).translation_statistics
        metrics = {"ate_rmse_m": unaligned.rmse, "ate_max_m": unaligned.max, "rpe_rmse_m": rpe.rmse,
                   "rpe_max_m": rpe.max, "alignment": "none", "alignment_note": f"not aligned: {exc}"}
    metrics["ate_rmse_unaligned_m"] = unaligned.rmse
    metrics["ate_max_unaligned_m"] = unaligned.max
    return metrics


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    return "—" if value is None else str(value)
