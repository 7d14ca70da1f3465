"""What every run reports about its input: frame counts and the ground-truth path."""

from __future__ import annotations

from collections import Counter

import numpy as np

from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.messages import FrameInfo, Message
from slamfront.report import plots


class FrameOverview(Evaluation):
    """Frames per traversal and, when the source knows poses, a top view of the path."""

    title = "Input"

    def __init__(self) -> None:
        self._counts: Counter[str] = Counter()
        self._positions: dict[str, list[np.ndarray]] = {}

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._counts[message.traversal] += 1
            if message.pose is not None:
                self._positions.setdefault(message.traversal, []).append(message.pose[:3, 3].copy())

    def finish(self, context: EvaluationContext) -> EvaluationReport:
        metrics = {"n_frames": int(sum(self._counts.values()))}
        metrics.update({f"n_frames_{name}": int(n) for name, n in sorted(self._counts.items())})
        lines = ["| traversal | frames |", "| --- | --- |"]
        lines += [f"| {name} | {n} |" for name, n in sorted(self._counts.items())]
        figures = []
        if context.options.plots and self._positions:
            paths = {name: np.array(points) for name, points in self._positions.items()}
            figures.append(
                plots.trajectories_2d(paths, context.out_dir / "trajectory.png", "ground-truth path").name
            )
        markdown = "\n".join(lines) + "\n\n" + "".join(f"![{f}]({f})\n\n" for f in figures)
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)
