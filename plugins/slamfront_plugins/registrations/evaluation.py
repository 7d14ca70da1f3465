"""Registration evaluation: relative pose error against the given poses, per pair and as
RMSE, quality and time of every step (Barbosa 2017's tables 9-11 layout), and the global
model written as ``model.ply``."""

from __future__ import annotations

import numpy as np

from slamfront.core.trajectory import delta_pairs, end_drift, relative_pose_error
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.formats.ply import write_ply
from slamfront.messages import FrameInfo, Message, PointCloud
from slamfront.report import plots
from slamfront_plugins.registrations.messages import CloudRegistration, RegisteredTrajectory

PREPROCESS_STEPS = ("cloud", "outliers", "downsample", "normals")
"""Per-frame steps reported together as preprocessing (RGB-D to a filtered, downsampled cloud)."""
REGISTERED = ("first", "aligned", "fallback")
"""Outcomes whose cloud is in the model."""
MAX_TABLE_ROWS = 300


class RegistrationEvaluation(Evaluation):
    """Scores a registration's poses against the source's and reports its steps and timings."""

    title = "Registration"

    def __init__(self) -> None:
        self._truth: dict[int, np.ndarray] = {}
        self._pairs: dict[int, CloudRegistration] = {}
        self._trajectory: RegisteredTrajectory | None = None
        self._model: PointCloud | None = None

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo) and message.pose is not None:
            self._truth[message.frame] = message.pose
        elif isinstance(message, CloudRegistration):
            self._pairs[message.frame] = message  # frozen, and it carries no cloud
        elif isinstance(message, RegisteredTrajectory):
            self._trajectory = message
        elif isinstance(message, PointCloud) and message.role == "model":
            self._model = message

    # -- metrics -------------------------------------------------------------------------

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        if not self._pairs:
            return None
        pairs = [self._pairs[f] for f in sorted(self._pairs)]
        outcomes = [p.outcome for p in pairs]
        chained = {p.frame: p.pose for p in pairs}
        final = chained
        if self._trajectory is not None and len(self._trajectory.frames):
            final = {int(f): pose for f, pose in zip(self._trajectory.frames, self._trajectory.poses)}
        registered = [p for p in pairs if p.outcome in ("aligned", "fallback")]
        metrics: dict[str, float | int | str | None] = {
            "n_clouds": sum(o in REGISTERED for o in outcomes),
            "n_pairs": sum(o in ("aligned", "fallback", "rejected") for o in outcomes),
            "n_aligned": outcomes.count("aligned"),
            "n_fallback": outcomes.count("fallback"),
            "n_rejected": outcomes.count("rejected"),
            "n_failed": outcomes.count("failed"),
            "fitness_mean": _mean([p.fitness for p in registered]),
            "inlier_rmse_mean_m": _mean([p.inlier_rmse for p in registered]),
        }
        per_frame = self._per_frame_errors(final)
        metrics.update(_rpe_metrics(per_frame, ""))
        refined = self._trajectory is not None and self._trajectory.refined
        if refined:
            metrics.update(_rpe_metrics(self._per_frame_errors(chained), "_chain"))
        metrics["end_to_end_error_m"] = self._end_to_end(final)
        metrics["pose_graph_refined"] = bool(refined)
        metrics["n_loop_edges"] = 0 if self._trajectory is None or self._trajectory.loop_edges is None else int(
            len(self._trajectory.loop_edges)
        )
        steps = self._step_seconds(pairs)
        metrics.update({f"seconds_{name}": value for name, value in steps.items()})
        if self._model is not None:
            metrics["model_points"] = int(len(self._model.points))
            write_ply(context.out_dir / "model.ply", self._model.points, self._model.colors)
            metrics["model_file"] = "model.ply"
        figures = self._plots(context, pairs, per_frame, final) if context.options.plots else []
        markdown = self._markdown(metrics, steps, pairs, per_frame, figures)
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)

    def _per_frame_errors(self, poses: dict[int, np.ndarray]) -> dict[int, tuple[float, float]]:
        """RPE of each frame against the previous frame with both poses: {frame: (m, deg)}."""
        frames = [f for f in sorted(poses) if f in self._truth]
        if len(frames) < 2:
            return {}
        estimated = np.stack([poses[f] for f in frames])
        truth = np.stack([self._truth[f] for f in frames])
        error = relative_pose_error(truth, estimated, delta_pairs(np.arange(len(frames)), 1))
        translation, rotation = error.translation, error.rotation_deg
        return {frames[k + 1]: (float(translation[k]), float(rotation[k])) for k in range(len(frames) - 1)}

    def _end_to_end(self, poses: dict[int, np.ndarray]) -> float | None:
        frames = [f for f in sorted(poses) if f in self._truth]
        if len(frames) < 2:
            return None
        estimated = np.stack([poses[frames[0]], poses[frames[-1]]])
        truth = np.stack([self._truth[frames[0]], self._truth[frames[-1]]])
        return end_drift(truth, estimated).translation_m

    def _step_seconds(self, pairs: list[CloudRegistration]) -> dict[str, float]:
        total: dict[str, float] = {}
        for pair in pairs:
            for step, seconds in pair.seconds.items():
                total[step] = total.get(step, 0.0) + seconds
        at_end = {} if self._trajectory is None else self._trajectory.seconds
        steps = {
            "preprocess": sum(total.get(s, 0.0) for s in PREPROCESS_STEPS),
            "features": total.get("features", 0.0),
            "initial_alignment": total.get("initial_alignment", 0.0),
            "icp": total.get("icp", 0.0),
            "pose_graph": at_end.get("loop_registration", 0.0) + at_end.get("pose_graph", 0.0),
            "model": at_end.get("model", 0.0),
        }
        steps["registration"] = sum(steps.values())
        return steps

    # -- report --------------------------------------------------------------------------

    def _markdown(
        self,
        metrics: dict[str, float | int | str | None],
        steps: dict[str, float],
        pairs: list[CloudRegistration],
        per_frame: dict[int, tuple[float, float]],
        figures: list[str],
    ) -> str:
        # the configured method is what the first attempts were called ("fpfh+ransac+icp",
        # "icp", "... (wider)"); "previous motion+icp" is a fallback's name
        configured = [p.method.split(" ")[0] for p in pairs if p.target >= 0 and not p.method.startswith("previous")]
        method = configured[0] if configured else "icp"
        feature, _, initial = method.partition("+")
        initial = initial.partition("+")[0]
        labels = {
            "preprocess": "preprocessing (cloud, outlier filter, voxel grid, normals)",
            "features": f"features ({feature.upper()})" if initial else "features (none)",
            "initial_alignment": f"initial alignment ({initial.upper() or 'none'})",
            "icp": "ICP",
            "pose_graph": "loop edges + pose graph",
            "model": "global model (concatenate, voxel grid)",
        }
        lines = [
            "| metric | value |",
            "| --- | --- |",
            *(f"| {key} | {_fmt(value)} |" for key, value in metrics.items() if not key.startswith("seconds_")),
            "",
            f"### Time per step ({len(pairs)} clouds; Barbosa 2017's tables 9-11 layout)",
            "",
            "| step | seconds | share |",
            "| --- | --- | --- |",
        ]
        total = steps["registration"] or 1.0
        for key, label in labels.items():
            lines.append(f"| {label} | {steps[key]:.3f} | {100 * steps[key] / total:.1f} % |")
        lines += [f"| **total** | **{steps['registration']:.3f}** | 100 % |", ""]
        lines += [
            "### Per pair",
            "",
            "RPE is this frame's pose relative to the previous frame's, against the given poses.",
            "",
            "| frame | target | outcome | method | points | fitness | inlier RMSE m | RPE m | RPE deg | "
            "preprocess s | features s | initial s | ICP s | note |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for pair in pairs[:MAX_TABLE_ROWS]:
            error_m, error_deg = per_frame.get(pair.frame, (None, None))
            s = pair.seconds
            lines.append(
                f"| {pair.frame} | {pair.target if pair.target >= 0 else ''} | {pair.outcome} | {pair.method} | "
                f"{pair.n_points} | {_fmt(pair.fitness)} | {_fmt(pair.inlier_rmse)} | {_fmt(error_m)} | "
                f"{_fmt(error_deg)} | {sum(s.get(k, 0.0) for k in PREPROCESS_STEPS):.3f} | "
                f"{s.get('features', 0.0):.3f} | {s.get('initial_alignment', 0.0):.3f} | {s.get('icp', 0.0):.3f} | "
                f"{pair.reason.replace('|', '/')} |"
            )
        if len(pairs) > MAX_TABLE_ROWS:
            lines.append(f"\n(first {MAX_TABLE_ROWS} of {len(pairs)} frames; all are in run.mcap)")
        lines.append("")
        lines += [f"![{name}]({name})\n" for name in figures]
        return "\n".join(lines)

    def _plots(
        self,
        context: EvaluationContext,
        pairs: list[CloudRegistration],
        per_frame: dict[int, tuple[float, float]],
        final: dict[int, np.ndarray],
    ) -> list[str]:
        out = context.out_dir
        figures = []
        frames = np.array(sorted(final), dtype=np.int64)
        paths = {"estimated": np.array([final[int(f)][:3, 3] for f in frames])}
        truth_frames = [f for f in frames if int(f) in self._truth]
        if truth_frames:
            paths = {"ground truth": np.array([self._truth[int(f)][:3, 3] for f in truth_frames]), **paths}
        # frames whose pose is a guess (rejected) or came from a fallback attempt, where they are
        flagged = {
            label: (np.array([final[p.frame][:3, 3] for p in pairs if p.outcome == outcome and p.frame in final])
                    .reshape(-1, 3), marker, plots.OUTCOME_COLOURS[outcome])
            for outcome, label, marker in (("fallback", "fallback", "^"), ("rejected", "rejected (pose guessed)", "X"))
        }
        figures.append(plots.trajectories_2d(
            paths, out / "registration_trajectory.png", "camera path", flagged=flagged
        ).name)
        if per_frame:
            keys = np.array(sorted(per_frame), dtype=np.int64)
            fitness = np.array([self._pairs[int(f)].fitness for f in keys], dtype=np.float64)
            figures.append(plots.pair_errors(
                keys, np.array([per_frame[int(f)][0] for f in keys]), np.array([per_frame[int(f)][1] for f in keys]),
                fitness, out / "registration_errors.png", "relative pose error per pair",
                outcomes=[self._pairs[int(f)].outcome for f in keys],
            ).name)
        step_frames = np.array([p.frame for p in pairs], dtype=np.int64)
        figures.append(plots.stacked_seconds(step_frames, {
            "preprocess": np.array([sum(p.seconds.get(k, 0.0) for k in PREPROCESS_STEPS) for p in pairs]),
            "features": np.array([p.seconds.get("features", 0.0) for p in pairs]),
            "initial alignment": np.array([p.seconds.get("initial_alignment", 0.0) for p in pairs]),
            "ICP": np.array([p.seconds.get("icp", 0.0) for p in pairs]),
        }, out / "registration_seconds.png", "time per step and frame").name)
        if self._model is not None:
            up = -np.mean([final[int(f)][:3, 1] for f in frames], axis=0)  # camera y points down
            figures.append(plots.cloud_top_view(
                self._model.points, self._model.colors, out / "model.png",
                f"global model, top view ({len(self._model.points)} points)", cameras=paths["estimated"], up=up,
            ).name)
        return figures


def _rpe_metrics(per_frame: dict[int, tuple[float, float]], suffix: str) -> dict[str, float | int | None]:
    translation = np.array([v[0] for v in per_frame.values()], dtype=np.float64)
    rotation = np.array([v[1] for v in per_frame.values()], dtype=np.float64)
    if len(translation) == 0:
        return {f"rpe_rmse_m{suffix}": None, f"n_rpe_pairs{suffix}": 0}
    return {
        f"rpe_rmse_m{suffix}": float(np.sqrt(np.mean(translation**2))),
        f"rpe_rot_rmse_deg{suffix}": float(np.sqrt(np.mean(rotation**2))),
        f"rpe_max_m{suffix}": float(translation.max()),
        f"rpe_median_m{suffix}": float(np.median(translation)),
        f"n_rpe_pairs{suffix}": int(len(translation)),
    }


def _mean(values: list[float]) -> float | None:
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def _fmt(value: object) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return "–" if not np.isfinite(value) else f"{value:.4g}"
    return str(value)
