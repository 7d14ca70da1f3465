"""Pose-graph text formats, parsed from and formatted to lines of text.

- **g2o** (Kümmerle et al., ICRA 2011): ``VERTEX_SE2 id x y theta``,
  ``EDGE_SE2 i j x y theta`` + the 6 upper-triangle entries of the information matrix,
  ``VERTEX_SE3:QUAT id x y z qx qy qz qw``, ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21
  upper-triangle entries, ``FIX id...``. Vertex lines are optional: without them the
  initial poses come from composing odometry. The 3-D rotation block of the
  information is taken as acting on the rotation vector, as GTSAM's ``readG2o`` does
  (strict g2o applies it to the quaternion's vector part, about half the angle).
- **iSAM** (Kaess et al.): ``EDGE2``/``ODOMETRY i j x y theta`` + 6 and
  ``EDGE3 i j x y z roll pitch yaw`` + 21 entries of the upper-triangular *square root*
  of the information matrix, row by row (information = R^T R), no vertex lines.

Landmark records of either format (``LANDMARK``, ``POINT3``, ``VERTEX_XY``, ...) are
counted and skipped: this is a pose-graph reader. Anything else is an error naming the
file and line. (Trajectory files are read by :mod:`slamfront.formats.poses` and
:mod:`slamfront.posegraph.io`.)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from slamfront.core import geometry
from slamfront.core.errors import CoreError
from slamfront.core.posegraph import PoseGraph, make_graph

GraphFormat = Literal["auto", "g2o", "isam"]


def _upper_to_symmetric(values: np.ndarray, k: int) -> np.ndarray:
    """(M, k(k+1)/2) row-major upper-triangle entries -> (M, k, k) symmetric matrices."""
    rows, cols = np.triu_indices(k)
    matrices = np.zeros((len(values), k, k))
    matrices[:, rows, cols] = values
    matrices[:, cols, rows] = values
    return matrices


def _upper_to_square_root_information(values: np.ndarray, k: int) -> np.ndarray:
    """(M, k(k+1)/2) entries of upper-triangular R -> (M, k, k) information R^T R."""
    rows, cols = np.triu_indices(k)
    roots = np.zeros((len(values), k, k))
    roots[:, rows, cols] = values
    return np.swapaxes(roots, 1, 2) @ roots


def _quaternion_rows(values: np.ndarray, lines: np.ndarray, name: str) -> np.ndarray:
    norms = np.linalg.norm(values, axis=1)
    bad = ~(norms > 1e-12)
    if np.any(bad):
        raise CoreError(f"{name}:{int(lines[np.argmax(bad)])}: quaternion has zero length")
    return values


@dataclass(frozen=True)
class _Record:
    """How to read one record type: its family, what it is, and how many numbers follow the tag."""

    family: Literal["g2o", "isam", "any"]
    role: Literal["vertex", "edge", "fix", "skip"]
    dim: int = 0
    n_numbers: int = 0
    convert: Callable[[np.ndarray, np.ndarray, str], tuple[np.ndarray, np.ndarray | None]] | None = None
    """(rows of numbers after the ids, line numbers, file name) -> (transforms, information or None)."""


def _g2o_se2_vertex(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, None]:
    return geometry.se2(numbers[:, 0], numbers[:, 1], numbers[:, 2]), None


def _g2o_se3_vertex(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, None]:
    return geometry.poses_from_quaternions(numbers[:, :3], _quaternion_rows(numbers[:, 3:7], lines, name)), None


def _g2o_se2_edge(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry.se2(numbers[:, 0], numbers[:, 1], numbers[:, 2]), _upper_to_symmetric(numbers[:, 3:], 3)


def _g2o_se3_edge(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    transforms = geometry.poses_from_quaternions(numbers[:, :3], _quaternion_rows(numbers[:, 3:7], lines, name))
    return transforms, _upper_to_symmetric(numbers[:, 7:], 6)


def _isam_2d_edge(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry.se2(numbers[:, 0], numbers[:, 1], numbers[:, 2]), _upper_to_square_root_information(numbers[:, 3:], 3)


def _isam_3d_edge(numbers: np.ndarray, lines: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    transforms = geometry.se3_from_euler(numbers[:, :3], numbers[:, 3:6])
    return transforms, _upper_to_square_root_information(numbers[:, 6:], 6)


RECORDS: Mapping[str, _Record] = {
    "VERTEX_SE2": _Record("g2o", "vertex", 2, 3, _g2o_se2_vertex),
    "EDGE_SE2": _Record("g2o", "edge", 2, 9, _g2o_se2_edge),
    "VERTEX_SE3:QUAT": _Record("g2o", "vertex", 3, 7, _g2o_se3_vertex),
    "EDGE_SE3:QUAT": _Record("g2o", "edge", 3, 28, _g2o_se3_edge),
    "FIX": _Record("g2o", "fix"),
    "EDGE2": _Record("isam", "edge", 2, 9, _isam_2d_edge),
    "ODOMETRY": _Record("isam", "edge", 2, 9, _isam_2d_edge),
    "EDGE3": _Record("isam", "edge", 3, 27, _isam_3d_edge),
    **{
        tag: _Record("any", "skip")
        for tag in (
            "LANDMARK", "POINT2", "POINT3", "VERTEX_XY", "EDGE_SE2_XY", "VERTEX_TRACKXYZ",
            "EDGE_SE3_TRACKXYZ", "VERTEX_POINTXYZ", "EDGE_SE3_POINTXYZ",
        )
    },
}
"""Every record tag the reader knows (see the module docstring)."""

_FOREIGN = {
    "VERTEX2": "TORO/.graph files (VERTEX2, VERTEX3) are not supported; convert them to g2o",
    "VERTEX3": "TORO/.graph files (VERTEX2, VERTEX3) are not supported; convert them to g2o",
}


@dataclass(frozen=True)
class ParsedGraph:
    """A graph read from text, with what the reader noticed.

    :ivar format: ``g2o`` or ``isam``.
    :ivar skipped: landmark records skipped, by tag.
    """

    graph: PoseGraph
    format: str
    skipped: dict[str, int] = field(default_factory=dict)
    plain_g2o: bool = False
    """Only g2o vertex and edge records of one kind, every vertex declared, ids and numbers
    that numpy's reader took (decimal, as C++ streams read them), no comments, FIX or landmarks: a
    file GTSAM's own ``readG2o`` reads into the same graph (see :mod:`slamfront.posegraph.solver`)."""


def _numbers(tokens: list[str], name: str, line: int, tag: str) -> list[float]:
    try:
        return [float(token) for token in tokens]
    except ValueError:
        bad = next(t for t in tokens if not is_number(t))
        raise CoreError(f"{name}:{line}: {tag}: {bad!r} is not a number") from None


def is_number(token: str) -> bool:
    """True when ``float(token)`` parses."""
    try:
        float(token)
    except ValueError:
        return False
    return True


_MAX_ID = (1 << 63) - 1  # ids are stored as int64


def _ids(tokens: list[str], name: str, line: int, tag: str) -> list[int]:
    try:
        ids = [int(token) for token in tokens]
    except ValueError:
        raise CoreError(f"{name}:{line}: {tag}: vertex ids must be integers, got {' '.join(tokens)!r}") from None
    if any(not -_MAX_ID <= i <= _MAX_ID for i in ids):
        raise CoreError(f"{name}:{line}: {tag}: a vertex id is outside the 64-bit range, got {' '.join(tokens)[:80]!r}")
    return ids


def parse_graph(lines: Iterable[str], name: str = "graph", graph_format: GraphFormat = "auto") -> ParsedGraph:
    """Parse a g2o or iSAM pose graph.

    :param lines: the file's lines.
    :param name: the file name, used in every error message (``name:line: ...``).
    :param graph_format: ``auto`` decides from the record tags (g2o's ``EDGE_SE2`` ...
        or iSAM's ``EDGE2``/``EDGE3``/``ODOMETRY``).
    :raises CoreError: unknown or malformed records, mixed 2-D and 3-D or mixed formats,
        unknown vertex ids, non-positive-definite information, an empty graph.
    """
    lines = lines if isinstance(lines, list) else list(lines)
    try:
        return _parse_regular(lines, name, graph_format)
    except _Irregular:  # read it again line by line: the first fault in file order is the one reported
        return _parse_checked(lines, name, graph_format)


class _Irregular(Exception):
    """The fast reader met something only the line-by-line reader reports (or accepts) properly."""


def _parse_regular(lines: list[str], name: str, graph_format: GraphFormat) -> ParsedGraph:
    """The whole file a record type at a time: lines grouped by tag, then each group
    converted in one pass by numpy's C reader (which reads integers and decimals as
    Python's ``int`` and ``float`` do, and checks every row has the same count). About
    three times as fast as :func:`_parse_checked` on a clean file; anything irregular (an
    unknown tag, a wrong count, a token numpy refuses) hands over to it, so errors and
    accepted spellings are its own."""
    grouped: dict[str, tuple[list[int], list[str]]] = {}
    commented = False
    for number, text in enumerate(lines, start=1):
        if "#" in text:
            text, commented = text.split("#", 1)[0], True
        parts = text.split(None, 1)
        if parts:
            entry = grouped.get(parts[0])
            if entry is None:
                entry = grouped[parts[0]] = ([], [])
            entry[0].append(number)
            entry[1].append(parts[1] if len(parts) > 1 else "")
    tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    fixed: list[int] = []
    skipped: dict[str, int] = {}
    families: dict[str, tuple[str, int]] = {}
    dims: dict[int, tuple[str, int]] = {}
    for tag, (numbers, rests) in sorted(grouped.items(), key=lambda item: item[1][0][0]):  # first seen first
        record = RECORDS.get(tag)
        if record is None:
            raise _Irregular
        if record.role == "skip":
            skipped[tag] = len(rests)
            continue
        families.setdefault(record.family, (tag, numbers[0]))
        if record.role == "fix":
            try:
                fixed.extend(i for number, rest in zip(numbers, rests) for i in _ids(rest.split(), name, number, tag))
            except CoreError:
                raise _Irregular from None
            continue
        dims.setdefault(record.dim, (tag, numbers[0]))
        n_ids = 1 if record.role == "vertex" else 2
        row = np.dtype([("ids", np.int64, (n_ids,)), ("numbers", np.float64, (record.n_numbers,))])
        try:  # numpy's integers and decimals: what Python's int and float read, less "1_0" and the like
            table = np.loadtxt(rests, dtype=row, comments=None, ndmin=1)
        except (ValueError, OverflowError):  # not a number, a row of another length, an id beyond 64 bits
            raise _Irregular from None
        if len(table) != len(rests) or np.any(table["ids"] < -_MAX_ID):  # a blank row; -2**63 is not an id
            raise _Irregular
        tables[tag] = (np.asarray(numbers, dtype=np.int64), table["ids"], table["numbers"])
    parsed = _finish(tables, fixed, skipped, families, dims, graph_format, name)
    plain = not (commented or fixed or skipped) and parsed.format == "g2o" and parsed.graph.poses is not None
    return ParsedGraph(parsed.graph, parsed.format, parsed.skipped, plain)


def _parse_checked(lines: list[str], name: str, graph_format: GraphFormat) -> ParsedGraph:
    """Line by line, each line checked as it is read (the first fault in file order is raised)."""
    rows: dict[str, list[tuple[int, list[int], list[float]]]] = {}
    fixed: list[int] = []
    skipped: dict[str, int] = {}
    families: dict[str, tuple[str, int]] = {}
    dims: dict[int, tuple[str, int]] = {}
    for number, text in enumerate(lines, start=1):
        tokens = text.split("#", 1)[0].split()
        if not tokens:
            continue
        tag = tokens[0]
        record = RECORDS.get(tag)
        if record is None:
            hint = _FOREIGN.get(tag, f"known records: {', '.join(t for t, r in RECORDS.items() if r.role != 'skip')}")
            raise CoreError(f"{name}:{number}: unknown record {tag!r} ({hint})")
        if record.role == "skip":
            skipped[tag] = skipped.get(tag, 0) + 1
            continue
        families.setdefault(record.family, (tag, number))
        if record.role == "fix":
            fixed.extend(_ids(tokens[1:], name, number, tag))
            continue
        dims.setdefault(record.dim, (tag, number))
        n_ids = 1 if record.role == "vertex" else 2
        expected = n_ids + record.n_numbers
        if len(tokens) - 1 != expected:
            raise CoreError(
                f"{name}:{number}: {tag} needs {expected} values ({n_ids} id{'s' if n_ids > 1 else ''} + "
                f"{record.n_numbers} numbers), got {len(tokens) - 1}"
            )
        ids = _ids(tokens[1 : 1 + n_ids], name, number, tag)
        values = _numbers(tokens[1 + n_ids :], name, number, tag)
        rows.setdefault(tag, []).append((number, ids, values))
    tables = {
        tag: (
            np.array([e[0] for e in entries], dtype=np.int64),
            np.array([e[1] for e in entries], dtype=np.int64),
            np.array([e[2] for e in entries], dtype=np.float64),
        )
        for tag, entries in rows.items()
    }
    return _finish(tables, fixed, skipped, families, dims, graph_format, name)


def _finish(
    tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    fixed: list[int],
    skipped: dict[str, int],
    families: dict[str, tuple[str, int]],
    dims: dict[int, tuple[str, int]],
    graph_format: GraphFormat,
    name: str,
) -> ParsedGraph:
    """The checks on the whole file, then the graph: ``tables`` holds, per tag, line
    numbers (R,), ids (R, 1 or 2) and numbers (R, K)."""
    resolved = _resolve_format(families, graph_format, name)
    if len(dims) > 1:
        (tag_a, line_a), (tag_b, line_b) = dims[2], dims[3]
        raise CoreError(f"{name}: mixes 2-D ({tag_a}, line {line_a}) and 3-D ({tag_b}, line {line_b}) records")
    if not any(RECORDS[tag].role == "edge" for tag in tables):
        raise CoreError(f"{name}: no edges found (an empty or non-graph file?)")
    dim = next(iter(dims))
    graph = _assemble(tables, dim, fixed, name)
    return ParsedGraph(graph, resolved, skipped)


def _resolve_format(families: dict[str, tuple[str, int]], requested: GraphFormat, name: str) -> str:
    found = [f for f in ("g2o", "isam") if f in families]
    if len(found) > 1:
        (tag_a, line_a), (tag_b, line_b) = families["g2o"], families["isam"]
        raise CoreError(f"{name}: mixes g2o ({tag_a}, line {line_a}) and iSAM ({tag_b}, line {line_b}) records")
    detected = found[0] if found else "g2o"
    if requested != "auto" and found and requested != detected:
        tag, line = families[detected]
        raise CoreError(f"{name}:{line}: {tag} is a {detected} record, but the format was given as {requested}")
    return detected


def _assemble(tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], dim: int, fixed: list[int], name: str) -> PoseGraph:
    vertex_ids, vertex_poses = [], []
    sources, targets, measurements, information, edge_lines = [], [], [], [], []
    for tag, (lines, ids, values) in tables.items():
        record = RECORDS[tag]
        bad = ~np.all(np.isfinite(values), axis=1)
        if np.any(bad):
            raise CoreError(f"{name}:{int(lines[np.argmax(bad)])}: {tag} has a non-finite number")
        assert record.convert is not None
        transforms, info = record.convert(values, lines, name)
        if record.role == "vertex":
            vertex_ids.append(ids[:, 0])
            vertex_poses.append(transforms)
        else:
            sources.append(ids[:, 0])
            targets.append(ids[:, 1])
            measurements.append(transforms)
            information.append(info)
            edge_lines.append(lines)
    edge_order = np.argsort(np.concatenate(edge_lines), kind="stable")  # keep file order across tags
    all_sources = np.concatenate(sources)[edge_order]
    all_targets = np.concatenate(targets)[edge_order]
    if vertex_ids:
        ids = np.concatenate(vertex_ids)
        poses: np.ndarray | None = np.concatenate(vertex_poses)
    else:
        ids = np.unique(np.concatenate([all_sources, all_targets]))
        poses = None
    return make_graph(
        dim=dim,
        ids=ids,
        poses=poses,
        sources=all_sources,
        targets=all_targets,
        measurements=np.concatenate(measurements)[edge_order],
        information=np.concatenate(information)[edge_order],
        name=name,
        lines=np.concatenate(edge_lines)[edge_order],
        fixed=np.asarray(fixed, dtype=np.int64),
    )


def _rows(tag: str, ids: list[np.ndarray], values: list[np.ndarray]) -> list[str]:
    """``tag id... value...`` lines, ids as integers and values as ``%.12g``,
    formatted a row at a time with one format string (several times faster than per value)."""
    table = np.column_stack([*(np.asarray(i, dtype=np.float64) for i in ids), *values])
    template = " ".join([tag, *["%d"] * len(ids), *["%.12g"] * (table.shape[1] - len(ids))])
    return [template % tuple(row) for row in table.tolist()]


def format_g2o(graph: PoseGraph, poses: np.ndarray | None = None) -> str:
    """The graph as g2o text: vertices (``poses``, else the graph's own, else none), edges, FIX.

    :param poses: (N, d+1, d+1) vertex poses to write in the order of ``graph.ids``.
    """
    poses = graph.poses if poses is None else np.asarray(poses, dtype=np.float64)
    out: list[str] = []
    k = graph.tangent_dim
    upper = np.triu_indices(k)
    information = graph.information[:, upper[0], upper[1]]
    if graph.dim == 2:
        if poses is not None:
            out += _rows("VERTEX_SE2", [graph.ids], [geometry.se2_parameters(poses)])
        out += _rows("EDGE_SE2", [graph.sources, graph.targets], [geometry.se2_parameters(graph.measurements), information])
    else:
        if poses is not None:
            out += _rows("VERTEX_SE3:QUAT", [graph.ids], [poses[:, :3, 3], geometry.quaternions_of(poses)])
        out += _rows(
            "EDGE_SE3:QUAT", [graph.sources, graph.targets],
            [graph.measurements[:, :3, 3], geometry.quaternions_of(graph.measurements), information],
        )
    if len(graph.fixed):
        out.append("FIX " + " ".join(str(int(v)) for v in graph.fixed))
    return "\n".join(out) + "\n"
