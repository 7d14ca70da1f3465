"""What every run reports about its input: frame counts and the ground-truth path, with
the loop closures drawn on it: verified, rejected and missed ones told apart; the ground
truth also goes to ``groundtruth.tum`` (the frames' own timestamps), for evo and the TUM tools."""

from __future__ import annotations

from collections import Counter

import numpy as np

from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport, PoseFile
from slamfront.messages import FrameInfo, LoopResult, LoopVerdict, Message
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
        self._checked: dict[tuple[int, int], bool] = {}
        """(frame, match) of each closure a back end checked -> whether it entered the graph."""

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._counts[message.traversal] += 1
            if message.pose is not None:
                self._positions[message.frame] = (message.traversal, message.sequence_index, message.pose[:3, 3].copy())
                self._stamped[message.frame] = (float(message.timestamp), np.asarray(message.pose, dtype=np.float64))
        elif isinstance(message, LoopResult) and message.accepted and message.match >= 0:
            self._accepted[message.frame] = message.match
        elif isinstance(message, LoopVerdict):
            self._checked[(message.frame, message.match)] = message.added

    def finish(self, context: EvaluationContext) -> EvaluationReport:
        metrics = {"n_frames": int(sum(self._counts.values()))}
        metrics.update({f"n_frames_{name}": int(n) for name, n in sorted(self._counts.items())})
        lines = ["| traversal | frames |", "| --- | --- |"]
        lines += [f"| {name} | {n} |" for name, n in sorted(self._counts.items())]
        figures = []
        if context.options.plots and self._positions:
            links, dots = self._loop_links(context)
            figures.append(plots.trajectories_2d(
                self._paths(), context.out_dir / "trajectory.png", "ground-truth path and loop closures",
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
        """The loop closures on the path, each kind its own colour, each count in the legend.

        A correct closure joins two visits of one place, so its line is as short as the
        revisit distance: closures are drawn as dots at the query's position, and only a
        wrong one that was kept (by the back end, or by a run without one) also as a line
        to the place it claimed. With a back end, what it verified and what it rejected are
        told apart; the queries that had a true match and got no correct closure are missed.
        """
        truth = context.source.loop_ground_truth()
        # (frame, match, outcome): a back end's decision on each closure it checked, and the
        # detector's accepted answers it never decided on (or all of them, without a back end)
        closures = [(f, m, "verified" if added else "rejected") for (f, m), added in self._checked.items()]
        closures += [(f, m, "accepted") for f, m in self._accepted.items() if (f, m) not in self._checked]
        closures = [c for c in closures if c[0] in self._positions and c[1] in self._positions]
        if not closures and truth is None:
            return {}, {}
        frames = np.array([c[0] for c in closures], dtype=np.int64)
        matches = np.array([c[1] for c in closures], dtype=np.int64)
        outcome = np.array([c[2] for c in closures])
        segments = np.array([[self._positions[f][2], self._positions[m][2]] for f, m, _ in closures]).reshape(-1, 2, 3)
        if truth is None:
            return {"loop closures": (segments, "tab:purple")}, {}
        scored = np.isin(frames, truth.queries)
        correct = np.zeros(len(closures), dtype=bool)
        correct[scored] = truth.is_correct(frames[scored], matches[scored])
        kept = outcome != "rejected"
        found = set(frames[correct].tolist())
        missed = [int(q) for q, has in zip(truth.queries, truth.has_true_match()) if has and int(q) not in found
                  and int(q) in self._positions]
        where = np.array([self._positions[q][2] for q in missed]).reshape(-1, 3)
        unchecked = "accepted, not checked by the back end" if self._checked else "accepted"
        dots = {
            "verified by the back end, correct": (segments[correct & (outcome == "verified"), 0], "o", "tab:green"),
            "verified by the back end, wrong": (segments[~correct & (outcome == "verified"), 0], "X", "tab:red"),
            f"{unchecked}, correct": (segments[correct & (outcome == "accepted"), 0], "o", "tab:cyan"),
            f"{unchecked}, wrong": (segments[~correct & (outcome == "accepted"), 0], "X", "tab:purple"),
            "rejected by the back end, correct": (segments[correct & ~kept, 0], "^", "tab:olive"),
            "rejected by the back end, wrong": (segments[~correct & ~kept, 0], "v", "tab:orange"),
            "missed (a true revisit with no correct closure)": (where, ".", "tab:gray"),
        }
        links = {"kept but wrong (line to the place it claimed)": (segments[~correct & kept], "tab:red")}
        return links, {label: value for label, value in dots.items() if len(value[0])}
