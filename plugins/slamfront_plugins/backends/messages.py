"""The back-end plugins' own log messages, declared through ``slamfront_message_types``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from slamfront.messages import LoopVerdict, Message, PoseGraphRecord


@dataclass(frozen=True, eq=False)
class LoopConstraint(Message, LoopVerdict):
    """The back end's decision on one loop closure: added to the graph, or skipped and why."""

    schema_name: ClassVar[str] = "slamfront.LoopConstraint"
    plain_fields: ClassVar[tuple[str, ...]] = ("transform",)
    frame: int
    match: int
    added: bool
    reason: str
    transform: np.ndarray | None = None
    """(4, 4) float64 pose of ``frame`` in ``match``'s camera, when verified."""
    inliers: int = 0

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        verdict = "added" if self.added else "skipped"
        text = f"loop closure {self.match} -> {self.frame} {verdict}: {self.reason}"
        return [("log", foxglove.log_line(text, stamp_ns, "info" if self.added else "warning", "backend"))]


@dataclass(frozen=True, eq=False)
class PoseGraphState(Message, PoseGraphRecord):
    """A pose graph as a back end built it, with its initial and optimised poses.

    ``slamfront optimize run.mcap`` re-optimises it; Foxglove shows its loop closures
    as line markers between the optimised positions.
    """

    schema_name: ClassVar[str] = "slamfront.PoseGraphState"
    dim: int
    vertices: np.ndarray
    """(N,) int64 vertex ids (frame indices), ascending."""
    initial: np.ndarray
    """(N, d+1, d+1) float64 poses before optimisation."""
    sources: np.ndarray
    """(M,) int64 edge start vertices."""
    targets: np.ndarray
    """(M,) int64 edge end vertices."""
    measurements: np.ndarray
    """(M, d+1, d+1) float64 measured T_source^-1 T_target."""
    information: np.ndarray
    """(M, k, k) float64 information, translation first (k = 3 or 6)."""
    optimised: np.ndarray | None = None
    """(N, d+1, d+1) float64 poses after optimisation, when done."""

    @classmethod
    def from_graph(cls, graph: Any, initial: np.ndarray, optimised: np.ndarray | None) -> PoseGraphState:
        """From a :class:`slamfront.core.posegraph.PoseGraph` and its poses."""
        return cls(
            dim=graph.dim, vertices=graph.ids, initial=initial, sources=graph.sources, targets=graph.targets,
            measurements=graph.measurements, information=graph.information, optimised=optimised,
        )

    def to_graph(self, name: str = "log") -> Any:
        """The :class:`slamfront.core.posegraph.PoseGraph` (validated; raises CoreError)."""
        from slamfront.core.posegraph import make_graph

        return make_graph(
            dim=self.dim, ids=self.vertices, poses=self.initial, sources=self.sources, targets=self.targets,
            measurements=self.measurements, information=self.information, name=name,
        )

    def loop_segments(self) -> np.ndarray:
        """(L, 2, d) endpoints of the loop closures (non-consecutive ids) at the latest poses."""
        poses = self.optimised if self.optimised is not None else self.initial
        loops = np.abs(self.targets - self.sources) != 1
        index = np.searchsorted(self.vertices, np.stack([self.sources[loops], self.targets[loops]], axis=1))
        return poses[index, : self.dim, self.dim]

    def foxglove(self, stamp_ns: int) -> list[tuple[str, Any]]:
        from slamfront.mcaplog import foxglove

        segments = self.loop_segments()
        if self.dim == 2:  # Foxglove draws in 3-D: planar graphs at z = 0
            segments = np.concatenate([segments, np.zeros((*segments.shape[:2], 1))], axis=-1)
        entity = foxglove.line_entity("loop_closures", segments, stamp_ns, (0.9, 0.1, 0.1, 1.0), strip=False)
        return [("loop_closures", foxglove.scene_update([entity]))]
