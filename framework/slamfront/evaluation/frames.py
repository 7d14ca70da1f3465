"""What every run reports about its input: frame counts and the ground-truth path, with
the loop closures the detector accepted drawn on it; the ground truth also goes to
``groundtruth.tum`` (the frames' own timestamps), for evo and the TUM tools."""

from __future__ import annotations

from collections import Counter

import numpy as np

from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport, PoseFile
from slamfront.messages import FrameInfo, LoopResult, Message
from slamfront.report import plots


class FrameOverview(Evaluation):
    """Frames per traversal and, when the source knows poses, a top view of the path."""

    title = "Input"

    def __init__(self) -> None:
        self._counts: Counter[str] = Counter()
        self._positions: dict[int, tuple[str, int, np.ndarray]] = {}
        """Frame -> (traversal, sequence index, true position)."""
        self._accepted: dict[int, int] = {}
        """Query frame -> the match the loop detector accepted."""
        self._stamped: dict[int, tuple[float, np.ndarray]] = {}
        """Frame -> (timestamp, true camera-to-world pose)."""

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._counts[message.traversal] += 1
            if message.pose is not None:
                self._positions[message.frame] = (message.traversal, message.sequence_index, message.pose[:3, 3].copy())
                self._stamped[message.frame] = (float(message.timestamp), np.asarray(message.pose, dtype=np.float64))
        elif isinstance(message, LoopResult) and message.accepted and message.match >= 0:
            self._accepted[message.frame] = message.match

    def finish(self, context: EvaluationContext) -> EvaluationReport:
        metrics = {"n_frames": int(sum(self._counts.values()))}
        metrics.update({f"n_frames_{name}": int(n) for name, n in sorted(self._counts.items())})
        lines = ["| traversal | frames |", "| --- | --- |"]
        lines += [f"| {name} | {n} |" for name, n in sorted(self._counts.items())]
        figures = []
        if context.options.plots and self._positions:
            links, dots = self._loop_links(context)
            figures.append(plots.trajectories_2d(
                self._paths(), context.out_dir / "trajectory.png", "ground-truth path and accepted loop closures",
                links=links, flagged=dots,
            ).name)
        trajectories = {}
        if self._stamped:
            stamped = sorted(self._stamped.values(), key=lambda item: item[0])
            trajectories["groundtruth"] = PoseFile(np.array([t for t, _ in stamped]), np.stack([p for _, p in stamped]))
            lines += ["", f"Ground truth of {len(stamped)} frames: `groundtruth.tum` (TUM format, the frames' timestamps)."]
        markdown = "\n".join(lines) + "\n\n" + "".join(f"![{f}]({f})\n\n" for f in figures)
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures,
                                trajectories=trajectories)

    def _paths(self) -> dict[str, np.ndarray]:
        """Each traversal's positions in route order (its sequence index), not arrival
        order: a shuffled (kidnapped) drive still draws as the road it was."""
        paths: dict[str, list[tuple[int, np.ndarray]]] = {}
        for traversal, sequence_index, position in self._positions.values():
            paths.setdefault(traversal, []).append((sequence_index, position))
        return {
            name: np.array([p for _, p in sorted(points, key=lambda item: item[0])])
            for name, points in paths.items()
        }

    def _loop_links(
        self, context: EvaluationContext
    ) -> tuple[dict[str, tuple[np.ndarray, str]], dict[str, tuple[np.ndarray, str, str]]]:
        """Accepted loop closures as lines between the two true positions, and their query
        frames as dots: correct ones green, wrong ones red. A correct closure joins two
        visits of one place, so its line is about as short as the revisit distance: the dot
        shows it."""
        pairs = [(f, m) for f, m in self._accepted.items() if f in self._positions and m in self._positions]
        if not pairs:
            return {}, {}
        frames = np.array([f for f, _ in pairs], dtype=np.int64)
        matches = np.array([m for _, m in pairs], dtype=np.int64)
        segments = np.array([[self._positions[f][2], self._positions[m][2]] for f, m in pairs])
        truth = context.source.loop_ground_truth()
        if truth is None:
            return {"accepted loop closures": (segments, "tab:purple")}, {}
        scored = np.isin(frames, truth.queries)
        correct = np.zeros(len(pairs), dtype=bool)
        correct[scored] = truth.is_correct(frames[scored], matches[scored])
        links = {
            "accepted loop closures, correct": (segments[correct], "tab:green"),
            "accepted loop closures, wrong": (segments[~correct], "tab:red"),
        }
        dots = {
            "query of a correct closure": (segments[correct, 0], "o", "tab:green"),
            "query of a wrong closure": (segments[~correct, 0], ".", "tab:red"),
        }
        return links, dots
