"""Localization evaluation: how right the localizer's answers are, how sure it was, and
ATE/RPE of its poses against the ground truth.

The ground truth of a frame is what the source said about it (association by frame
index, exact): its pose, and its scene. A frame whose scene is not one of the map's
(``mixed_scenes`` adds such frames) is *out of the map*: every answer given for it is
wrong. An answer for an in-map frame is right when the chosen keyframe lies in the
frame's region of the map (:meth:`LocalizationEvaluation._region_correct`).

- **Precision-recall** over the localizer's confidence, in-map and out-of-map frames
  together (recall counts in-map frames with a ground-truth pose), with recall at 100 %
  precision and the operating point (the answers the localizer actually gave).
- **ATE and RPE** (:mod:`slamfront.core.trajectory`, the functions ``slamfront eval traj``
  uses) of the in-map frames it localized, in route order (traversal, then the dataset's
  own numbering), so the order frames arrived in changes nothing. ``ate_rmse_m`` /
  ``rpe_rmse_m`` score the chosen keyframe's pose, as Barbosa 2017's tables; with PnP
  refinement ``ate_rmse_pnp_m`` / ``rpe_rmse_pnp_m`` score the refined poses of the same
  frames. ATE after rigid Horn alignment (and ``*_unaligned_m`` without); RPE over
  consecutive frames (delta 1) and over all intervals (``rpe_all_intervals_*``, Sturm et
  al. 2012's average, Barbosa 2017's table 6).
- The map the run built goes to ``keyframe_map.npz`` (when the localizer kept its
  features), for ``localizer.params.map`` in a later run.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamfront.core.errors import CoreError
from slamfront.core.loops import PrecisionRecall, precision_recall
from slamfront.core.trajectory import absolute_trajectory_error, delta_pairs, evaluate_poses, relative_pose_error
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport, PoseFile
from slamfront.formats.npz import write_message_npz
from slamfront.messages import FrameInfo, Message
from slamfront.report import plots
from slamfront_plugins.localizers.messages import KeyframeAdded, KeyframeMap, PoseEstimate

MAP_FILE = "keyframe_map.npz"
"""Where a run saves the keyframe map it built (``localizer.params.map`` reads it)."""

# metrics of the refined poses: the keyframe-pose key on the left, the PnP one on the right
_PNP_KEYS = {
    "ate_rmse_m": "ate_rmse_pnp_m", "ate_max_m": "ate_max_pnp_m", "ate_median_m": "ate_median_pnp_m",
    "rpe_rmse_m": "rpe_rmse_pnp_m", "rpe_max_m": "rpe_max_pnp_m",
    "rpe_all_intervals_rmse_m": "rpe_all_intervals_rmse_pnp_m", "rpe_all_intervals_max_m": "rpe_all_intervals_max_pnp_m",
    "ate_rmse_unaligned_m": "ate_rmse_pnp_unaligned_m", "ate_max_unaligned_m": "ate_max_pnp_unaligned_m",
}


@dataclass(frozen=True)
class _Truth:
    timestamp: float
    traversal: str
    sequence_index: int
    pose: np.ndarray | None
    scene: str


class LocalizationEvaluation(Evaluation):
    """Scores every ``PoseEstimate`` against its frame's ground truth."""

    title = "Localization"

    def __init__(self) -> None:
        self._truth: dict[int, _Truth] = {}
        self._estimates: dict[int, PoseEstimate] = {}
        self._added: dict[int, np.ndarray | None] = {}
        self._map: KeyframeMap | None = None
        self._scenes: set[str] = {""}
        self._positions: dict[int, np.ndarray] = {}

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._truth[message.frame] = _Truth(message.timestamp, message.traversal, message.sequence_index,
                                                message.pose, message.scene)
        elif isinstance(message, PoseEstimate):
            self._estimates[message.frame] = message
        elif isinstance(message, KeyframeAdded):
            self._added[message.frame] = message.pose
        elif isinstance(message, KeyframeMap):
            self._map = message

    # --- the map ------------------------------------------------------------------------

    def _keyframe_poses(self) -> dict[int, np.ndarray]:
        """Keyframe frame index -> pose, in node order (a loaded map has no KeyframeAdded)."""
        if self._map is not None and self._map.poses is not None:
            return {int(f): p for f, p in zip(self._map.frames.tolist(), self._map.poses)}
        return {f: p for f, p in self._added.items() if p is not None}

    def _map_scenes(self) -> set[str]:
        if self._map is not None and self._map.scenes:
            return set(self._map.scenes)
        scenes = {self._truth[f].scene for f in self._added if f in self._truth}
        return scenes or {""}

    def _in_map(self, frame: int) -> bool:
        truth = self._truth.get(frame)
        return truth is None or truth.scene in self._scenes

    # --- finish -------------------------------------------------------------------------

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        n_keyframes = len(self._map.frames) if self._map is not None else len(self._added)
        saved = self._save_map(context.out_dir)
        if not self._estimates:
            return EvaluationReport(self.title, metrics={"n_keyframes": n_keyframes},
                                    markdown="No frame was localized (no PoseEstimate messages).\n")
        self._scenes = self._map_scenes()
        self._positions = self._keyframe_poses()
        estimates = [self._estimates[f] for f in sorted(self._estimates)]
        localized = [e for e in estimates if e.keyframe >= 0]
        in_map = [e for e in estimates if self._in_map(e.frame)]
        out_of_map = [e for e in estimates if not self._in_map(e.frame)]
        trajectories: dict[str, PoseFile] = {}
        metrics: dict[str, float | int | str | None] = {
            "n_keyframes": n_keyframes,
            "n_localization_queries": len(estimates),
            "n_frames_localized": len(localized),
            "n_too_few_features": sum(e.reason.startswith("too few features") for e in estimates),
            "n_unknown_place": sum(e.reason.startswith("unknown place") for e in estimates),
            "fraction_localized": len(localized) / len(estimates),
            "n_refined": sum(e.refined for e in estimates),
            "n_in_map_queries": len(in_map),
            "n_out_of_map_queries": len(out_of_map),
        }
        if out_of_map:
            wrong = sum(e.keyframe >= 0 for e in out_of_map)
            metrics["n_out_of_map_localized"] = wrong
            metrics["fraction_out_of_map_refused"] = 1.0 - wrong / len(out_of_map)
        # a keyframe without a pose (no ground truth for it) localizes topologically only
        scored = [e for e in localized if e.pose is not None and self._in_map(e.frame)
                  and self._truth.get(e.frame) is not None and self._truth[e.frame].pose is not None]
        figures: list[str] = []
        notes = []
        curve = self._precision_recall(estimates, metrics)
        if scored:
            metrics.update(self._trajectory_metrics(scored))
            metrics.update(self._region_metrics(scored))
            trajectories, written = self._trajectories(scored)
            notes += written
        else:
            notes.append("No localized in-map frame has a ground-truth pose: no ATE/RPE.")
        if context.options.plots:
            # in-map frames with a true pose that got none: marked on the trajectory and error plots
            lost = [e for e in estimates if e.keyframe < 0 and self._in_map(e.frame)
                    and self._truth.get(e.frame) is not None and self._truth[e.frame].pose is not None]
            figures = self._plots(context.out_dir, scored, curve, metrics, lost)
        reasons = Counter(re.sub(r"\d+(\.\d+)?", "N", e.reason) for e in estimates if e.keyframe < 0)
        if reasons:
            notes.append("Not localized: " + "; ".join(f"{n} x {why}" for why, n in reasons.most_common()) + ".")
        if out_of_map:
            notes.append(f"{len(out_of_map)} frames of other scenes (out of the map) were queried too; "
                         f"{metrics['n_out_of_map_localized']} of them were given a pose (each one a wrong answer).")
        if saved:
            notes.append(f"The map is saved as `{MAP_FILE}`: `--set localizer.params.map=<run folder>/{MAP_FILE}` "
                         "localizes a later run against it.")
        # the localizer's own timings are already in metrics.json (stage statistics); show them here too
        shown = {**metrics, **{k: v for k, v in context.statistics.items() if k.startswith("localization_latency")}}
        table = "\n".join(["| metric | value |", "| --- | --- |", *(f"| {k} | {_fmt(v)} |" for k, v in shown.items())])
        markdown = "\n\n".join([*notes, table, *(f"![{f}]({f})" for f in figures)]) + "\n"
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures,
                                trajectories=trajectories)

    def _save_map(self, out_dir: Path) -> bool:
        if self._map is None or self._map.descriptors is None:
            return False
        write_message_npz(out_dir / MAP_FILE, self._map)
        return True

    # --- right and wrong answers --------------------------------------------------------

    def _spacing(self) -> float:
        return keyframe_spacing(np.array([p[:3, 3] for p in self._positions.values()]).reshape(-1, 3))

    def _region_correct(self, frame: int, keyframe: int) -> bool | None:
        """Is ``keyframe`` in ``frame``'s region of the map (:func:`in_region`)? None when a pose is unknown."""
        truth = self._truth.get(frame)
        if truth is None or truth.pose is None or keyframe not in self._positions:
            return None
        positions = np.array([p[:3, 3] for p in self._positions.values()], dtype=np.float64)
        return in_region(positions, self._positions[keyframe][:3, 3], truth.pose[:3, 3], self._spacing())

    def _precision_recall(self, estimates: list[PoseEstimate], metrics: dict) -> PrecisionRecall | None:
        """PR over the confidence: in-map frames with a pose can be right, out-of-map ones never."""
        correct, confidence, answered, accepted = [], [], [], []
        positives = 0
        for e in estimates:
            candidate = int(e.candidates[0]) if e.candidates is not None and len(e.candidates) else -1
            inside = self._in_map(e.frame)
            truth = self._truth.get(e.frame)
            positives += inside and truth is not None and truth.pose is not None and bool(self._positions)
            correct.append(inside and candidate >= 0 and bool(self._region_correct(e.frame, candidate)))
            confidence.append(e.confidence)
            answered.append(candidate >= 0)
            accepted.append(e.keyframe >= 0)
        if positives == 0:
            return None
        curve = precision_recall(np.array(confidence), np.array(answered), np.array(correct), positives)
        given = np.array(accepted) & np.array(answered)
        right = int(np.sum(given & np.array(correct)))
        metrics.update({
            "localization_recall_at_100p": curve.recall_at_100p,
            "localization_auc_pr": curve.auc,
            "localization_threshold_at_100p": curve.threshold_at_100p(),
            "localization_precision": right / max(int(given.sum()), 1),
            "localization_recall": right / positives,
            "n_in_map_with_pose": positives,
        })
        return curve

    def _region_metrics(self, scored: list[PoseEstimate]) -> dict[str, float | int]:
        if not self._positions:
            return {}
        correct = sum(bool(self._region_correct(e.frame, e.keyframe)) for e in scored)
        chosen = [float(np.linalg.norm(e.keyframe_pose[:3, 3] - self._truth[e.frame].pose[:3, 3])) for e in scored]
        return {
            "fraction_correct_keyframe_region": correct / len(scored),
            "n_wrong_keyframe_region": len(scored) - correct,
            "keyframe_spacing_m": self._spacing(),
            "keyframe_distance_median_m": float(np.median(chosen)),
            "keyframe_distance_max_m": float(np.max(chosen)),
        }

    # --- trajectories -------------------------------------------------------------------

    def _route(self, scored: list[PoseEstimate]) -> list[PoseEstimate]:
        """``scored`` along the route: traversal, then the dataset's own numbering (not arrival order)."""
        return sorted(scored, key=lambda e: (self._truth[e.frame].traversal, self._truth[e.frame].sequence_index,
                                             e.frame))

    def _trajectory_metrics(self, scored: list[PoseEstimate]) -> dict[str, float | int | str]:
        route = self._route(scored)
        gt = np.stack([self._truth[e.frame].pose for e in route])
        metrics = _scores(gt, np.stack([e.keyframe_pose for e in route]))
        if any(e.refined for e in route):
            refined = _scores(gt, np.stack([e.pose for e in route]))
            metrics.update({pnp: refined[key] for key, pnp in _PNP_KEYS.items() if key in refined})
        return metrics

    def _trajectories(self, scored: list[PoseEstimate]) -> tuple[dict[str, PoseFile], list[str]]:
        """TUM trajectories for the runtime to write, and report notes on reproducing the numbers.

        ``estimated.tum`` (and ``estimated_pnp.tum``) carry the frames' own timestamps, so
        they pair with the run's ``groundtruth.tum``. When frames arrived out of route
        order (a kidnapped robot), RPE is scored along the route: ``*_route.tum`` list the
        frames in route order stamped with the run's timestamps sorted, so tools that
        order by time see the route."""
        route = self._route(scored)
        own = np.array([self._truth[e.frame].timestamp for e in route], dtype=np.float64)
        order = np.argsort(own, kind="stable")
        keyframe_poses = np.stack([e.keyframe_pose for e in route])
        refined = any(e.refined for e in route)
        pnp_poses = np.stack([e.pose for e in route]) if refined else None
        files = {"estimated": PoseFile(own[order], keyframe_poses[order])}
        if pnp_poses is not None:
            files["estimated_pnp"] = PoseFile(own[order], pnp_poses[order])
        names = "`estimated.tum`" + (" (keyframe poses; `estimated_pnp.tum`: refined)" if refined else "")
        notes = [
            f"Trajectories in TUM format, with the frames' timestamps: {names}, and the run's `groundtruth.tum`. "
            "`slamfront eval traj groundtruth.tum estimated.tum` and `evo_ape tum groundtruth.tum estimated.tum -a` "
            "give `ate_rmse_m`."
        ]
        if np.any(np.diff(own) <= 0):
            route_stamps = np.sort(own)
            gt = np.stack([self._truth[e.frame].pose for e in route])
            files["groundtruth_route"] = PoseFile(route_stamps, gt)
            files["estimated_route"] = PoseFile(route_stamps, keyframe_poses)
            if pnp_poses is not None:
                files["estimated_pnp_route"] = PoseFile(route_stamps, pnp_poses)
            notes.append(
                "Frames arrived out of route order, and RPE is scored along the route: `groundtruth_route.tum` "
                "`estimated_route.tum` list them in route order, stamped with the run's timestamps in increasing "
                "order; `evo_rpe tum groundtruth_route.tum estimated_route.tum -a` gives `rpe_rmse_m` (delta 1 "
                "frame; add `--delta N --all_pairs` for other deltas)."
            )
        else:
            notes.append("`evo_rpe tum groundtruth.tum estimated.tum -a` gives `rpe_rmse_m` (delta 1 frame; add "
                         "`--delta N --all_pairs` for other deltas).")
        return files, notes

    # --- plots --------------------------------------------------------------------------

    def _plots(self, out_dir: Path, scored: list[PoseEstimate], curve: PrecisionRecall | None,
               metrics: dict, lost: list[PoseEstimate]) -> list[str]:
        """The PR curve; top view and error along the route (spikes circled, frames not localized marked)."""
        figures = []
        if curve is not None:
            pr = plots.localization_pr(
                curve.recall, curve.precision,
                (float(metrics["localization_recall"]), float(metrics["localization_precision"])),
                curve.recall_at_100p, out_dir / "localization_pr.png",
                f"localization PR ({metrics['n_in_map_queries']} in-map, "
                f"{metrics['n_out_of_map_queries']} out-of-map frames)",
            )
            figures.append(pr.name)
        if not scored:
            return figures
        route = self._route(scored)
        gt = np.stack([self._truth[e.frame].pose[:3, 3] for e in route])
        est = np.stack([e.pose[:3, 3] for e in route])
        keyframes = np.array([p[:3, 3] for p in self._positions.values()]).reshape(-1, 3)
        trajectory = plots.localization_plot(
            gt, est, keyframes, out_dir / "localization.png", "estimated vs ground-truth trajectory",
            lost=np.array([self._truth[e.frame].pose[:3, 3] for e in lost]).reshape(-1, 3),
        )
        errors = np.linalg.norm(est - gt, axis=1)
        error = plots.error_along(
            np.array([self._truth[e.frame].sequence_index for e in route], dtype=np.float64), errors,
            out_dir / "localization_error.png", "position error per frame (unaligned)", "sequence index",
            "error [m]", missing=np.array([self._truth[e.frame].sequence_index for e in lost], dtype=np.float64),
        )
        return [*figures, trajectory.name, error.name]


def keyframe_spacing(positions: np.ndarray) -> float:
    """Median distance between consecutive (K, 3) keyframe positions in node order (0 for fewer than 2)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(positions) < 2:
        return 0.0
    return float(np.median(np.linalg.norm(np.diff(positions, axis=0), axis=1)))


def in_region(keyframes: np.ndarray, chosen: np.ndarray, truth: np.ndarray, spacing: float) -> bool:
    """Is the keyframe at ``chosen`` in the map region of a frame truly at ``truth``?

    Yes when it is no more than two keyframe spacings farther from ``truth`` than the
    nearest of the (K, 3) ``keyframes``: the nearest node or one of its two neighbours
    either way along the route, which see the same scene.
    """
    nearest = float(np.min(np.linalg.norm(np.asarray(keyframes, dtype=np.float64) - truth, axis=1)))
    return float(np.linalg.norm(np.asarray(chosen, dtype=np.float64) - truth)) <= nearest + 2.0 * spacing + 1e-9


def _scores(gt: np.ndarray, est: np.ndarray) -> dict[str, float | int | str]:
    """ATE/RPE (route order) after rigid alignment, and ATE without; unaligned only when alignment is undetermined."""
    unaligned = absolute_trajectory_error(gt, est, "none").statistics
    try:
        metrics = evaluate_poses(gt, est, None, "se3", delta=1, delta_unit="frames", all_intervals=True).metrics()
    except CoreError as exc:  # fewer than 3 poses, or every estimate at one keyframe
        rpe = relative_pose_error(gt, est, delta_pairs(np.arange(len(gt), dtype=np.float64), 1)).translation_statistics
        metrics = {"ate_rmse_m": unaligned.rmse, "ate_max_m": unaligned.max, "rpe_rmse_m": rpe.rmse,
                   "rpe_max_m": rpe.max, "alignment": "none", "alignment_note": f"not aligned: {exc}"}
    metrics["ate_rmse_unaligned_m"] = unaligned.rmse
    metrics["ate_max_unaligned_m"] = unaligned.max
    return metrics


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    return "—" if value is None else str(value)
