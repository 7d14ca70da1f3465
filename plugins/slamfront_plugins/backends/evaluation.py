"""Back-end evaluation: ATE and RPE (Sturm et al. 2012, :mod:`slamfront.core.trajectory`)
of the trajectory before and after pose-graph optimisation, its drift (the position
error of the last pose relative to the first, per distance travelled), loop closures the
back end added (and how many of them were true), and a plot. The two trajectories go to
``odometry.tum`` and ``optimised.tum`` (the frames' own timestamps): ``evo_ape tum
groundtruth.tum optimised.tum -a`` gives ``ate_rmse_after_m``."""

from __future__ import annotations

import numpy as np

from slamfront.core.trajectory import end_drift, evaluate_poses
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport, PoseFile
from slamfront.messages import FrameInfo, Message, Trajectory
from slamfront.posegraph import report
from slamfront_plugins.backends.messages import LoopConstraint, PoseGraphState

_SOLVER_KEYS = (
    "backend_mode", "backend_kernel", "n_vertices", "n_edges", "n_graph_loop_closures", "cost_before", "cost_after",
    "iterations", "converged", "optimisation_seconds", "n_rejected_edges",
)
"""Back-end statistics (already in metrics.json) repeated in the report section."""


class BackendEvaluation(Evaluation):
    """Scores the back end's ``odometry`` and ``optimised`` trajectories against the
    source's ground-truth poses (ATE after a rigid alignment)."""

    title = "Pose-graph back end"
    labels = ("odometry", "optimised")

    def __init__(self) -> None:
        self._truth: dict[int, np.ndarray] = {}
        self._stamps: dict[int, float] = {}
        self._trajectories: dict[str, Trajectory] = {}
        self._graph: PoseGraphState | None = None
        self._constraints: list[LoopConstraint] = []

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._stamps[message.frame] = float(message.timestamp)
            if message.pose is not None:
                self._truth[message.frame] = np.asarray(message.pose, dtype=np.float64)
        elif isinstance(message, Trajectory) and message.label in self.labels:
            self._trajectories[message.label] = message
        elif isinstance(message, PoseGraphState):
            self._graph = message
        elif isinstance(message, LoopConstraint):
            self._constraints.append(message)

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        if not self._trajectories:
            return EvaluationReport(self.title, markdown="The back end produced no trajectory.\n")
        added = [c for c in self._constraints if c.added]
        metrics: dict[str, float | int | None] = {
            "n_loop_constraints_added": len(added),
            "n_loop_constraints_skipped": len(self._constraints) - len(added),
        }
        truth = context.source.loop_ground_truth()
        if truth is not None and added:
            frames = np.array([c.frame for c in added], dtype=np.int64)
            known = np.isin(frames, truth.queries)
            correct = truth.is_correct(frames[known], np.array([c.match for c in added], dtype=np.int64)[known])
            metrics["n_loop_constraints_added_false"] = int(len(correct) - correct.sum())
        estimate = self._trajectories.get("optimised") or next(iter(self._trajectories.values()))
        frames = estimate.frames
        has_truth = len(frames) >= 3 and all(int(f) in self._truth for f in frames)
        truth_poses = np.array([self._truth[int(f)] for f in frames]) if has_truth else None
        ground_truth = None if truth_poses is None else truth_poses[:, :3, 3]
        positions = {label: t.poses[:, :3, 3] for label, t in self._trajectories.items()}
        if truth_poses is not None and np.ptp(ground_truth, axis=0).max() > 0:
            for label, suffix in (("odometry", "before"), ("optimised", "after")):
                if label in self._trajectories:
                    scores = evaluate_poses(truth_poses, self._trajectories[label].poses).metrics()
                    metrics[f"ate_rmse_{suffix}_m"] = scores["ate_rmse_m"]
                    metrics[f"rpe_rmse_{suffix}_m"] = scores["rpe_rmse_m"]
                    metrics[f"rpe_rotation_rmse_{suffix}_deg"] = scores["rpe_rotation_rmse_deg"]
                    drift = end_drift(truth_poses, self._trajectories[label].poses)
                    metrics[f"drift_{suffix}_m"] = drift.translation_m
                    metrics[f"drift_{suffix}_percent"] = drift.percent
        figures = []
        if context.options.plots:
            loops = None
            if self._graph is not None:
                mask = np.abs(self._graph.targets - self._graph.sources) != 1
                loops = np.searchsorted(frames, np.stack([self._graph.sources[mask], self._graph.targets[mask]], 1))
            keys = {"odometry": "ate_rmse_before_m", "optimised": "ate_rmse_after_m"}
            titled = {
                label + (f" (ATE {metrics[keys[label]]:.3g} m)" if keys[label] in metrics else ""): points
                for label, points in positions.items()
            }
            path = report.before_after(titled, context.out_dir / "backend.png", ground_truth, loops,
                                       title="trajectory before and after pose-graph optimisation")
            figures.append(path.name)
        # a key another stage also reports (a place map's n_vertices) is in metrics.json as backend.<key>
        shown = {
            k: context.statistics.get(f"backend.{k}", context.statistics[k])
            for k in _SOLVER_KEYS if k in context.statistics
        }
        trajectories = self._stamped()
        note = ""
        if trajectories:
            note = (f"Trajectories in TUM format (the frames' timestamps): {', '.join(f'`{n}.tum`' for n in trajectories)}"
                    ". `evo_ape tum groundtruth.tum optimised.tum -a` (rigid SE(3) alignment, translation part) gives "
                    "`ate_rmse_after_m`, with `odometry.tum` `ate_rmse_before_m`.\n\n")
        markdown = (report.metrics_table({**shown, **metrics}) + "\n\n" + note
                    + "".join(f"![{f}]({f})\n\n" for f in figures))
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures,
                                trajectories=trajectories)

    def _stamped(self) -> dict[str, PoseFile]:
        """The back end's trajectories stamped with their frames' timestamps, in time order."""
        stamped = {}
        for label, trajectory in self._trajectories.items():
            frames = [int(f) for f in trajectory.frames]
            if not frames or not all(f in self._stamps for f in frames):
                continue
            stamps = np.array([self._stamps[f] for f in frames], dtype=np.float64)
            order = np.argsort(stamps, kind="stable")
            stamped[label] = PoseFile(stamps[order], np.asarray(trajectory.poses, dtype=np.float64)[order])
        return stamped
