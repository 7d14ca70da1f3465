"""What Foxglove's 3-D panel draws besides the camera: the path so far and loop closures.

The scene is a ``foxglove.SceneUpdate`` on ``/scene/map`` (frame ``map``) holding the
ground-truth path of each traversal and a line from every accepted loop closure's query
pose to its match's pose. Each update holds the whole scene so far, so Foxglove shows
it completely after a seek. Updates are written every ``every`` frames, less often as a
run grows (never more often than every 1/32 of the frames so far, so a long run writes
O(log n) updates, not O(n)), and at the end; the path is thinned to at most
``max_points`` points per traversal. That keeps the topic small on long runs.
"""

from __future__ import annotations

import numpy as np

from slamfront.mcaplog import foxglove
from slamfront.mcaplog.topics import SCENE_TOPIC
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.messages import FrameInfo, LoopResult, Message

_COLOURS = {
    "reference": (0.2, 0.45, 0.95, 1.0),
    "query": (0.95, 0.55, 0.1, 1.0),
    "stream": (0.6, 0.6, 0.6, 1.0),
}
_LOOP_COLOUR = (0.1, 0.85, 0.3, 1.0)


class SceneLogger:
    """Observes frames and loop results; writes the scene every ``every`` frames."""

    def __init__(self, every: int = 20, max_points: int = 2000, max_loops: int = 5000) -> None:
        self.every = every
        self.max_points = max_points
        self.max_loops = max_loops
        self._position: dict[int, np.ndarray] = {}
        self._path: dict[str, list[np.ndarray]] = {}
        self._loops: list[tuple[int, int]] = []
        self._frames_seen = 0
        self._next_write = every
        self._dirty = False

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._frames_seen += 1
            if message.pose is not None:
                position = np.asarray(message.pose[:3, 3], dtype=np.float64)
                self._position[message.frame] = position
                self._path.setdefault(message.traversal, []).append(position)
                self._dirty = True
        elif isinstance(message, LoopResult) and message.accepted and message.match >= 0:
            if message.frame in self._position and message.match in self._position:
                self._loops.append((message.frame, message.match))
                self._dirty = True

    def after_frame(self, log: RunLogWriter, stamp_ns: int) -> None:
        """Called after each frame; writes an update when one is due."""
        if self._frames_seen >= self._next_write:
            self._next_write = self._frames_seen + max(self.every, self._frames_seen // 32)
            self.write(log, stamp_ns)

    def write(self, log: RunLogWriter, stamp_ns: int) -> None:
        """Write the scene now if anything changed since the last update."""
        if not self._dirty:
            return
        self._dirty = False
        entities = []
        for traversal, points in self._path.items():
            path = np.asarray(points)
            if len(path) > self.max_points:
                path = path[np.linspace(0, len(path) - 1, self.max_points).round().astype(int)]
            colour = _COLOURS.get(traversal, _COLOURS["stream"])
            entities.append(foxglove.line_entity(f"path/{traversal}", path, stamp_ns, colour, strip=True))
        loops = self._loops[-self.max_loops :]
        segments = np.array(
            [(self._position[a], self._position[b]) for a, b in loops], dtype=np.float64
        ).reshape(-1, 3)
        entities.append(foxglove.line_entity("loop_closures", segments, stamp_ns, _LOOP_COLOUR, strip=False))
        log.write_foxglove(SCENE_TOPIC, foxglove.scene_update(entities), stamp_ns)
