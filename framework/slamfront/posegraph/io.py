"""Reading pose graphs and ground truth from files and run logs; writing results.

Errors name the file (and line) and are :class:`~slamfront.errors.DataError`, so the
CLI reports them in one line with exit code 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamfront.core import geometry
from slamfront.core.errors import CoreError
from slamfront.core.graph_files import RECORDS, GraphFormat, ParsedGraph, format_g2o, is_number, parse_graph
from slamfront.core.posegraph import PoseGraph, compose_initial_poses
from slamfront.errors import DataError
from slamfront.formats import poses as pose_files
from slamfront.outputs import write_atomically


def read_lines(path: Path) -> list[str]:
    """A text file's lines.

    :raises DataError: missing, unreadable, a folder, or not text.
    """
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.readlines()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DataError(f"{path}: is a folder, not a file") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text file") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror or exc}") from None


def _parse(lines: list[str], name: str, graph_format: GraphFormat) -> ParsedGraph:
    try:
        return parse_graph(lines, name, graph_format)
    except CoreError as exc:
        raise DataError(str(exc)) from None


@dataclass(frozen=True)
class LoadedGraph:
    """A graph from a file or log, and ground truth found beside it.

    :ivar ground_truth: (N, d) true positions of the graph's vertices when the input
        carries them (a run log's frame poses), else None.
    """

    parsed: ParsedGraph
    ground_truth: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    """(N,) seconds of the graph's vertices when the input carries them (a run log's
    frame times), else None: the TUM files then use the vertex ids."""


def read_graph(path: Path, graph_format: GraphFormat = "auto") -> LoadedGraph:
    """A g2o or iSAM file, or the pose graph a back end logged in a run's ``run.mcap``."""
    path = Path(path)
    if path.suffix == ".mcap":
        return graph_from_log(path)
    return LoadedGraph(_parse(read_lines(path), str(path), graph_format))


def graph_from_log(path: Path) -> LoadedGraph:
    """The last pose graph a back end logged in a run log (a message whose type is a
    :class:`~slamfront.messages.PoseGraphRecord`, among the installed message types), with
    the ground-truth poses of its frames when the source logged them.

    :raises LogError: not a readable log; DataError: no back-end graph in it.
    """
    from slamfront.mcaplog.reader import read_messages, summarize  # logs only: graph files do without
    from slamfront.message_types import installed_message_types
    from slamfront.messages import FrameInfo, PoseGraphRecord

    summary = summarize(path)
    types = installed_message_types()
    topics = [
        t.topic for t in summary.topics
        if t.message_encoding == "json" and issubclass(types.get(t.schema_name) or object, PoseGraphRecord)
    ]
    if not topics:
        raise DataError(f"{path}: the log has no pose graph (a back end's graph message); "
                        "run a recipe with a backend stage, or give a g2o file")
    state: PoseGraphRecord | None = None
    truth: dict[int, np.ndarray] = {}
    stamps: dict[int, float] = {}
    for logged in read_messages(path, topics=[*topics, "/frames"], strict=summary.complete, types=types):
        message = logged.decoded
        if isinstance(message, PoseGraphRecord):
            state = message
        elif isinstance(message, FrameInfo):
            stamps[message.frame] = float(message.timestamp)
            if message.pose is not None:
                truth[message.frame] = message.pose[:3, 3]
    assert state is not None
    try:
        graph = state.to_graph(name=str(path))
    except CoreError as exc:
        raise DataError(str(exc)) from None
    positions = None
    if truth and all(int(v) in truth for v in graph.ids):
        positions = np.array([truth[int(v)] for v in graph.ids])[:, : graph.dim]
    times = np.array([stamps[int(v)] for v in graph.ids]) if all(int(v) in stamps for v in graph.ids) else None
    return LoadedGraph(ParsedGraph(graph, "log"), positions, times)


def _is_graph_text(lines: list[str]) -> bool:
    for line in lines:
        tokens = line.split("#", 1)[0].split()
        if tokens:
            return tokens[0] in RECORDS or not is_number(tokens[0])
    return False


def read_xytheta(path: Path) -> pose_files.Trajectory:
    """``x y theta`` lines (planar poses, row i = vertex i), as planar poses embedded at z = 0."""
    rows = []
    for number, fields in pose_files.numbered_fields(path):
        if len(fields) != 3:
            raise DataError(f"{path}:{number}: expected 3 numbers (x y theta), got {len(fields)}")
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise DataError(f"{path}:{number}: not a number in {' '.join(fields)!r}") from None
    if not rows:
        raise DataError(f"{path}: no poses in the file")
    values = np.array(rows)
    if not np.all(np.isfinite(values)):
        raise DataError(f"{path}: non-finite value")
    planar = geometry.se2(values[:, 0], values[:, 1], values[:, 2])
    return pose_files.Trajectory(np.arange(len(values), dtype=np.float64), geometry.planar_to_spatial(planar))


_TRAJECTORY_READERS = {
    8: ("tum", pose_files.read_tum),
    7: ("pose lines", pose_files.read_pose_lines),
    12: ("kitti", pose_files.read_kitti),
    3: ("xytheta", read_xytheta),
}
"""Trajectory formats by their number of columns."""


def read_trajectory(path: Path) -> tuple[pose_files.Trajectory, str]:
    """A trajectory file of any format in :data:`_TRAJECTORY_READERS` and its format name.

    :raises DataError: an unknown column count, or a malformed row (file:line).
    """
    first = next(iter(pose_files.numbered_fields(path)), None)
    if first is None:
        raise DataError(f"{path}: no poses in the file")
    number, fields = first
    if len(fields) not in _TRAJECTORY_READERS:
        raise DataError(
            f"{path}:{number}: {len(fields)} columns; expected 8 (TUM: t x y z qx qy qz qw), 7 (x y z qx qy qz qw), "
            "3 (x y theta) or 12 (KITTI 3x4 matrix)"
        )
    name, reader = _TRAJECTORY_READERS[len(fields)]
    return reader(path), name


def read_ground_truth(path: Path, graph: PoseGraph) -> np.ndarray:
    """True positions (N, d) of ``graph``'s vertices, in the order of ``graph.ids``.

    Accepts a trajectory (TUM lines, ``x y theta`` lines, ``x y z qx qy qz qw`` lines,
    KITTI rows) or a noise-free graph file in any supported format, whose poses come from
    composing its odometry. Rows match vertex ids by line index or, for TUM, by timestamp
    when the timestamps are the vertex ids, else by order when there is one row per vertex.

    :raises DataError: the file does not cover the graph's vertices, or is malformed.
    """
    path = Path(path)
    lines = read_lines(path)
    if _is_graph_text(lines):
        try:
            truth = parse_graph(lines, str(path)).graph
            poses = compose_initial_poses(truth)
        except CoreError as exc:
            raise DataError(str(exc)) from None
        missing = ~np.isin(graph.ids, truth.ids)
        if np.any(missing):
            raise DataError(f"{path}: ground-truth graph has no vertex {int(graph.ids[np.argmax(missing)])}")
        if truth.dim < graph.dim:
            raise DataError(f"{path}: ground truth is 2-D but {graph.name} is a 3-D graph")
        return poses[truth.index_of(graph.ids), : graph.dim, truth.dim]
    trajectory, kind = read_trajectory(path)
    if kind == "xytheta" and graph.dim == 3:
        raise DataError(f"{path}: ground truth is 2-D (x y theta) but {graph.name} is a 3-D graph")
    return _trajectory_positions(trajectory, kind, graph, path)[:, : graph.dim]


def _trajectory_positions(trajectory: pose_files.Trajectory, kind: str, graph: PoseGraph, path: Path) -> np.ndarray:
    positions = trajectory.positions
    stamps = trajectory.timestamps
    if kind == "tum":
        as_ids = np.round(stamps).astype(np.int64)
        if np.allclose(stamps, as_ids) and np.all(np.isin(graph.ids, as_ids)):
            _, first = np.unique(as_ids, return_index=True)
            lookup = dict(zip(as_ids[first].tolist(), first.tolist()))
            return positions[[lookup[int(v)] for v in graph.ids]]
        if len(stamps) == graph.n_vertices:
            return positions
        raise DataError(
            f"{path}: {len(stamps)} TUM poses for {graph.n_vertices} vertices, and the timestamps are not the "
            "vertex ids: cannot tell which pose is which vertex"
        )
    if graph.ids[0] < 0 or graph.ids[-1] >= len(positions):
        raise DataError(
            f"{path}: {len(positions)} rows (vertex 0 to {len(positions) - 1}) do not cover vertex {int(graph.ids[-1])}"
        )
    return positions[graph.ids]


def write_g2o(path: Path, graph: PoseGraph, poses: np.ndarray) -> Path:
    """The graph with ``poses`` as its vertices, as g2o."""
    return write_atomically(path, format_g2o(graph, poses))


def write_tum(path: Path, graph: PoseGraph, poses: np.ndarray, timestamps: np.ndarray | None = None) -> Path:
    """Poses as a TUM trajectory (planar ones at z = 0), stamped with ``timestamps`` (the
    vertices' own times, seconds) when given, else with the vertex ids."""
    spatial = geometry.planar_to_spatial(poses) if graph.dim == 2 else np.asarray(poses)
    stamps = graph.ids.astype(np.float64) if timestamps is None else np.asarray(timestamps, dtype=np.float64)
    return pose_files.write_tum(path, pose_files.Trajectory(stamps, spatial))


@dataclass(frozen=True)
class OdometryTable:
    """Motion between frames read from a file, for a back end's odometry.

    Exactly one of the lookups is set: ``by_index`` (poses by frame index: ``x y theta``
    and KITTI rows, graph vertices), ``stamps``/``stamped`` (TUM poses by time), or
    ``relative`` (RelativePose messages of a run log, by (from, to) frame).
    """

    path: Path
    by_index: dict[int, np.ndarray] | None = None
    stamps: np.ndarray | None = None
    stamped: np.ndarray | None = None
    relative: dict[tuple[int, int], tuple[np.ndarray, np.ndarray | None]] | None = None
    max_time_difference: float = 0.02

    def between(self, previous: tuple[int, float], current: tuple[int, float]) -> tuple[np.ndarray, np.ndarray | None]:
        """(4, 4) motion from frame ``previous`` to ``current`` (each ``(index, timestamp)``)
        and its (6, 6) information when the file gives one.

        :raises DataError: the file has nothing for these frames.
        """
        if self.relative is not None:
            found = self.relative.get((previous[0], current[0]))
            if found is None:
                raise DataError(f"{self.path}: no RelativePose from frame {previous[0]} to frame {current[0]}")
            return found
        return geometry.relative(self._pose(*previous), self._pose(*current)), None

    def _pose(self, index: int, stamp: float) -> np.ndarray:
        if self.by_index is not None:
            if index not in self.by_index:
                raise DataError(f"{self.path}: no pose for frame {index}")
            return self.by_index[index]
        assert self.stamps is not None and self.stamped is not None
        nearest = int(np.argmin(np.abs(self.stamps - stamp)))
        if abs(self.stamps[nearest] - stamp) > self.max_time_difference:
            raise DataError(
                f"{self.path}: no pose within {self.max_time_difference} s of frame {index} (t = {stamp:.3f} s)"
            )
        return self.stamped[nearest]


def _spatial(poses: np.ndarray) -> np.ndarray:
    return geometry.planar_to_spatial(poses) if geometry.dimension_of(poses) == 2 else poses


def read_odometry(path: Path) -> OdometryTable:
    """Odometry for a run from a trajectory file (TUM, ``x y theta``, KITTI), a graph
    file (its composed poses, vertex id = frame index) or a run log (RelativePose messages).
    """
    path = Path(path)
    if path.suffix == ".mcap":
        from slamfront.mcaplog.reader import read_messages, summarize
        from slamfront.messages import RelativePose

        summary = summarize(path)
        topics = [t.topic for t in summary.topics if t.schema_name == RelativePose.schema_name]
        if not topics:
            raise DataError(f"{path}: the log has no {RelativePose.schema_name} messages to take odometry from")
        relative = {}
        for logged in read_messages(path, topics=topics, strict=summary.complete):
            message = logged.decoded
            relative[(message.frame_from, message.frame_to)] = (message.transform, message.information)
        return OdometryTable(path, relative=relative)
    lines = read_lines(path)
    if _is_graph_text(lines):
        try:
            graph = parse_graph(lines, str(path)).graph
            poses = _spatial(compose_initial_poses(graph))
        except CoreError as exc:
            raise DataError(str(exc)) from None
        return OdometryTable(path, by_index=dict(zip(graph.ids.tolist(), poses)))
    trajectory, kind = read_trajectory(path)
    if kind == "tum":
        return OdometryTable(path, stamps=trajectory.timestamps, stamped=trajectory.poses)
    return OdometryTable(path, by_index=dict(enumerate(trajectory.poses)))
