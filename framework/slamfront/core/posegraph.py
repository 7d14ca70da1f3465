"""Pose graphs as arrays: vertices with initial poses, relative-pose edges with information.

Conventions: an edge ``s -> t`` measures ``T_s^-1 T_t`` (the pose of vertex ``t`` in the
frame of vertex ``s``), as in g2o. Information matrices are in the tangent order
``(x, y, theta)`` for SE(2) and ``(x, y, z, rx, ry, rz)`` for SE(3), translation first,
as g2o files store them. An edge between consecutive vertex ids is odometry; any other
edge is a loop closure.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from slamfront.core import geometry
from slamfront.core.errors import CoreError


def _int_array(values: np.ndarray | list[int]) -> np.ndarray:
    return np.asarray(values, dtype=np.int64).reshape(-1)


@dataclass(frozen=True)
class PoseGraph:
    """A 2-D or 3-D pose graph.

    :ivar dim: 2 (SE(2)) or 3 (SE(3)).
    :ivar ids: (N,) int64 vertex ids, sorted, unique.
    :ivar poses: (N, d+1, d+1) initial poses in the order of ``ids``, or None when the
        source gave none (see :func:`compose_initial_poses`).
    :ivar sources: (M,) int64 vertex id each edge starts from.
    :ivar targets: (M,) int64 vertex id each edge ends at.
    :ivar measurements: (M, d+1, d+1) measured ``T_source^-1 T_target``.
    :ivar information: (M, k, k) information matrices, k = 3 or 6 (module docstring).
    :ivar fixed: (F,) int64 ids of vertices held at their initial pose.
    :ivar name: where the graph came from, for messages (a file name).
    :ivar lines: (M,) int64 1-based line of each edge in that file, or None.
    """

    dim: int
    ids: np.ndarray
    poses: np.ndarray | None
    sources: np.ndarray
    targets: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    fixed: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    name: str = "graph"
    lines: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.dim not in (2, 3):
            raise CoreError(f"{self.name}: a pose graph is 2-D or 3-D, not {self.dim}-D")
        n, m, side, k = len(self.ids), len(self.sources), self.dim + 1, self.tangent_dim
        if len(self.ids) > 1 and np.any(np.diff(self.ids) <= 0):
            raise CoreError(f"{self.name}: vertex ids must be sorted and unique")
        if self.poses is not None and self.poses.shape != (n, side, side):
            raise CoreError(f"{self.name}: poses must have shape {(n, side, side)}, got {self.poses.shape}")
        if self.targets.shape != (m,) or self.measurements.shape != (m, side, side):
            raise CoreError(f"{self.name}: edge arrays disagree in length or shape")
        if self.information.shape != (m, k, k):
            raise CoreError(f"{self.name}: information must have shape {(m, k, k)}, got {self.information.shape}")
        if self.lines is not None and self.lines.shape != (m,):
            raise CoreError(f"{self.name}: lines must have one entry per edge")

    @property
    def tangent_dim(self) -> int:
        """3 for SE(2), 6 for SE(3)."""
        return 3 if self.dim == 2 else 6

    @property
    def n_vertices(self) -> int:
        return len(self.ids)

    @property
    def n_edges(self) -> int:
        return len(self.sources)

    def index_of(self, ids: np.ndarray) -> np.ndarray:
        """Positions of vertex ``ids`` in :attr:`ids`.

        :raises CoreError: naming the first id that is not a vertex.
        """
        ids = _int_array(ids)
        positions = np.searchsorted(self.ids, ids).clip(0, max(len(self.ids) - 1, 0))
        missing = (len(self.ids) == 0) | (self.ids[positions] != ids) if len(ids) else np.zeros(0, dtype=bool)
        if np.any(missing):
            raise CoreError(f"{self.name}: no vertex with id {int(ids[np.argmax(missing)])}")
        return positions

    def is_odometry(self) -> np.ndarray:
        """(M,) bool: edges between consecutive ids (the rest are loop closures)."""
        return np.abs(self.targets - self.sources) == 1

    def where(self, edge: int) -> str:
        """``file:line`` of an edge when known, else ``file: edge s -> t``."""
        if self.lines is not None:
            return f"{self.name}:{int(self.lines[edge])}"
        return f"{self.name}: edge {int(self.sources[edge])} -> {int(self.targets[edge])}"

    def with_poses(self, poses: np.ndarray) -> PoseGraph:
        """A copy with other vertex poses, (N, d+1, d+1)."""
        return replace(self, poses=np.asarray(poses, dtype=np.float64).copy())

    def with_edges(
        self, sources: np.ndarray, targets: np.ndarray, measurements: np.ndarray, information: np.ndarray
    ) -> PoseGraph:
        """A copy with more edges appended (their line numbers are 0: not from the file)."""
        lines = None if self.lines is None else np.concatenate([self.lines, np.zeros(len(_int_array(sources)), np.int64)])
        return replace(
            self,
            sources=np.concatenate([self.sources, _int_array(sources)]),
            targets=np.concatenate([self.targets, _int_array(targets)]),
            measurements=np.concatenate([self.measurements, np.asarray(measurements, dtype=np.float64)]),
            information=np.concatenate([self.information, np.asarray(information, dtype=np.float64)]),
            lines=lines,
        )


def make_graph(
    dim: int,
    ids: np.ndarray,
    poses: np.ndarray | None,
    sources: np.ndarray,
    targets: np.ndarray,
    measurements: np.ndarray,
    information: np.ndarray,
    name: str = "graph",
    lines: np.ndarray | None = None,
    fixed: np.ndarray | None = None,
) -> PoseGraph:
    """Build and check a graph from unsorted inputs: vertices are sorted by id.

    :raises CoreError: duplicate vertex ids, an edge naming an unknown vertex or itself,
        a non-finite value, or an information matrix that is not symmetric positive
        definite; the message names the file and line when ``lines`` is given.
    """
    ids = _int_array(ids)
    order = np.argsort(ids, kind="stable")
    ids = ids[order]
    duplicate = np.flatnonzero(np.diff(ids) == 0)
    if len(duplicate):
        raise CoreError(f"{name}: vertex {int(ids[duplicate[0]])} is declared twice")
    side = dim + 1
    sources, targets = _int_array(sources), _int_array(targets)
    measurements = np.asarray(measurements, dtype=np.float64).reshape(-1, side, side)
    graph = PoseGraph(
        dim=dim,
        ids=ids,
        poses=None if poses is None else np.asarray(poses, dtype=np.float64).reshape(-1, side, side)[order],
        sources=sources,
        targets=targets,
        measurements=measurements,
        information=np.asarray(information, dtype=np.float64).reshape(len(sources), 3 * (dim - 1), 3 * (dim - 1)),
        fixed=np.empty(0, dtype=np.int64) if fixed is None else _int_array(fixed),
        name=name,
        lines=None if lines is None else _int_array(lines),
    )
    check_graph(graph)
    return graph


def check_graph(graph: PoseGraph) -> None:
    """Validate edges and information.

    :raises CoreError: see :func:`make_graph`.
    """
    loops = np.flatnonzero(graph.sources == graph.targets)
    if len(loops):
        raise CoreError(f"{graph.where(loops[0])}: edge connects vertex {int(graph.sources[loops[0]])} to itself")
    for endpoint in (graph.sources, graph.targets):
        known = np.isin(endpoint, graph.ids)
        if not np.all(known):
            bad = int(np.argmin(known))
            raise CoreError(
                f"{graph.where(bad)}: edge {int(graph.sources[bad])} -> {int(graph.targets[bad])} refers to vertex "
                f"{int(endpoint[bad])}, which no VERTEX record declares"
            )
    unknown_fixed = ~np.isin(graph.fixed, graph.ids)
    if np.any(unknown_fixed):
        raise CoreError(f"{graph.name}: FIX names vertex {int(graph.fixed[np.argmax(unknown_fixed)])}, which does not exist")
    finite = np.all(np.isfinite(graph.measurements.reshape(graph.n_edges, -1)), axis=1)
    finite &= np.all(np.isfinite(graph.information.reshape(graph.n_edges, -1)), axis=1)
    if not np.all(finite):
        raise CoreError(f"{graph.where(int(np.argmin(finite)))}: non-finite measurement or information")
    if graph.poses is not None and not np.all(np.isfinite(graph.poses)):
        raise CoreError(f"{graph.name}: a vertex pose is not finite")
    check_information(graph)


def check_information(graph: PoseGraph) -> None:
    """Each information matrix must be symmetric positive definite (a Gaussian's inverse covariance).

    :raises CoreError: naming the first offending edge and its smallest eigenvalue.
    """
    if graph.n_edges == 0:
        return
    info = graph.information
    scale = np.maximum(np.abs(info).reshape(len(info), -1).max(axis=1), 1e-300)
    asymmetric = np.abs(info - np.swapaxes(info, 1, 2)).reshape(len(info), -1).max(axis=1) > 1e-6 * scale
    if np.any(asymmetric):
        raise CoreError(f"{graph.where(int(np.argmax(asymmetric)))}: information matrix is not symmetric")
    smallest = np.linalg.eigvalsh(info)[:, 0]
    bad = smallest <= 1e-12 * scale
    if np.any(bad):
        edge = int(np.argmax(bad))
        raise CoreError(
            f"{graph.where(edge)}: information matrix of edge {int(graph.sources[edge])} -> "
            f"{int(graph.targets[edge])} is not positive definite (smallest eigenvalue {smallest[edge]:.3g})"
        )


def components(graph: PoseGraph) -> np.ndarray:
    """(N,) connected-component label of each vertex (0 is the first vertex's)."""
    n = graph.n_vertices
    labels = connected_labels(n, graph.index_of(graph.sources), graph.index_of(graph.targets))
    if n:
        labels = np.where(labels == labels[0], 0, labels + (labels < labels[0]))  # first vertex's label -> 0
    return labels


def connected_labels(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) component of each of ``n`` vertices joined by undirected edges ``a[i] - b[i]``,
    numbered in the order of their lowest vertex (SciPy's ``connected_components``).

    A graph whose edges join every vertex to the next (an odometry chain, as nearly every
    pose graph has) is one piece without asking SciPy, whose import (~0.1 s) would be a
    tenth of ``slamfront optimize`` on a graph of a few thousand poses.
    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    consecutive = np.zeros(max(n - 1, 0), dtype=bool)
    low, step = np.minimum(a, b), np.abs(a - b)
    consecutive[low[step == 1]] = True
    if consecutive.all():
        return np.zeros(n, dtype=np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adjacency = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))  # duplicate edges add up
    return connected_components(adjacency, directed=False)[1].astype(np.int64)


def check_connected(graph: PoseGraph) -> None:
    """An optimisable graph is one piece: otherwise each extra piece floats freely.

    :raises CoreError: naming how many vertices are cut off and a few of their ids.
    """
    if graph.n_vertices == 0:
        raise CoreError(f"{graph.name}: the graph has no vertices")
    labels = components(graph)
    cut = np.flatnonzero(labels != 0)
    if len(cut):
        sample = ", ".join(str(int(v)) for v in graph.ids[cut[:5]])
        raise CoreError(
            f"{graph.name}: the graph is disconnected: {int(labels.max()) + 1} pieces; {len(cut)} vertices "
            f"(e.g. {sample}) have no chain of edges to vertex {int(graph.ids[0])}"
        )


def spanning_tree(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """A spanning tree from the first vertex that prefers odometry edges.

    0-1 breadth-first search: an odometry edge costs 0, a loop closure 1, so every
    vertex the odometry chain reaches is reached through it.

    :returns: ``order`` (N,) vertex positions in the order reached, and ``parent_edge``
        (N,) the edge index that reached each vertex (-1 for the root).
    :raises CoreError: the graph is disconnected.
    """
    check_connected(graph)
    n = graph.n_vertices
    src, dst = graph.index_of(graph.sources), graph.index_of(graph.targets)
    odometry = graph.is_odometry()
    neighbours: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for edge, (a, b) in enumerate(zip(src.tolist(), dst.tolist())):
        neighbours[a].append((b, edge))
        neighbours[b].append((a, edge))
    cost = np.full(n, np.iinfo(np.int64).max)
    parent_edge = np.full(n, -1, dtype=np.int64)
    done = np.zeros(n, dtype=bool)
    order: list[int] = []
    cost[0] = 0
    queue: deque[int] = deque([0])
    while queue:
        vertex = queue.popleft()
        if done[vertex]:
            continue
        done[vertex] = True
        order.append(vertex)
        for other, edge in neighbours[vertex]:
            step = 0 if odometry[edge] else 1
            if not done[other] and cost[vertex] + step < cost[other]:
                cost[other] = cost[vertex] + step
                parent_edge[other] = edge
                if step == 0:
                    queue.appendleft(other)
                else:
                    queue.append(other)
    return np.asarray(order, dtype=np.int64), parent_edge


def compose_initial_poses(graph: PoseGraph, anchor: np.ndarray | None = None) -> np.ndarray:
    """Initial poses by composing measurements along :func:`spanning_tree` (odometry first).

    :param anchor: (d+1, d+1) pose of the first vertex; identity when None.
    :returns: (N, d+1, d+1) poses in the order of ``graph.ids``.
    """
    order, parent_edge = spanning_tree(graph)
    side = graph.dim + 1
    poses = np.empty((graph.n_vertices, side, side))
    poses[order[0]] = np.eye(side) if anchor is None else anchor
    src, dst = graph.index_of(graph.sources), graph.index_of(graph.targets)
    inverse_measurements = geometry.invert(graph.measurements)
    for vertex in order[1:]:
        edge = parent_edge[vertex]
        if dst[edge] == vertex:
            poses[vertex] = poses[src[edge]] @ graph.measurements[edge]
        else:
            poses[vertex] = poses[dst[edge]] @ inverse_measurements[edge]
    return poses


def initial_poses(graph: PoseGraph) -> np.ndarray:
    """The graph's own initial poses, or odometry composed from the first vertex."""
    return graph.poses.copy() if graph.poses is not None else compose_initial_poses(graph)


def subgraph(graph: PoseGraph, keep: np.ndarray) -> PoseGraph:
    """The vertices with ids in ``keep`` and the edges between them."""
    keep_mask = np.isin(graph.ids, _int_array(keep))
    edge_mask = np.isin(graph.sources, graph.ids[keep_mask]) & np.isin(graph.targets, graph.ids[keep_mask])
    return replace(
        graph,
        ids=graph.ids[keep_mask],
        poses=None if graph.poses is None else graph.poses[keep_mask],
        sources=graph.sources[edge_mask],
        targets=graph.targets[edge_mask],
        measurements=graph.measurements[edge_mask],
        information=graph.information[edge_mask],
        fixed=graph.fixed[np.isin(graph.fixed, graph.ids[keep_mask])],
        lines=None if graph.lines is None else graph.lines[edge_mask],
    )


def random_false_closures(
    graph: PoseGraph, outlier_rate: float, rng: np.random.Generator, min_separation: int = 10
) -> tuple[PoseGraph, np.ndarray]:
    """Add random wrong loop closures so they make up ``outlier_rate`` of all loop closures.

    Each false closure joins two random vertices at least ``min_separation`` ids apart;
    its measurement is a random rigid motion (translation uniform within the median
    length of the true loop closures in each axis, rotation uniform) and it carries the
    median information of the true loop closures, so it is as confident as they are,
    like a place-recognition false positive that passed verification.

    :param outlier_rate: in [0, 1): false / (false + true) loop closures.
    :returns: the corrupted graph and (M',) bool marking the added edges.
    """
    if not 0.0 <= outlier_rate < 1.0:
        raise CoreError(f"outlier rate must be in [0, 1), got {outlier_rate}")
    loops = ~graph.is_odometry()
    n_true = int(loops.sum())
    n_false = round(outlier_rate / (1.0 - outlier_rate) * n_true)
    if n_false == 0:
        return graph, np.zeros(graph.n_edges, dtype=bool)
    if graph.n_vertices <= min_separation:
        raise CoreError(f"{graph.name}: too few vertices to add closures {min_separation} ids apart")
    reference = loops if n_true else np.ones(graph.n_edges, dtype=bool)
    d = graph.dim
    reach = float(np.median(np.linalg.norm(graph.measurements[reference, :d, d], axis=1))) or 1.0
    information = np.median(graph.information[reference], axis=0)
    first, second = _distant_pairs(graph.n_vertices, n_false, min_separation, rng)
    translation = rng.uniform(-reach, reach, size=(n_false, d))
    if d == 2:
        measurements = geometry.se2(translation[:, 0], translation[:, 1], rng.uniform(-np.pi, np.pi, n_false))
    else:
        quaternions = rng.normal(size=(n_false, 4))
        measurements = geometry.poses_from_quaternions(translation, quaternions)
    corrupted = graph.with_edges(
        graph.ids[first], graph.ids[second], measurements, np.repeat(information[None], n_false, axis=0)
    )
    return corrupted, np.r_[np.zeros(graph.n_edges, dtype=bool), np.ones(n_false, dtype=bool)]


def _distant_pairs(n: int, count: int, min_separation: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` random position pairs at least ``min_separation`` apart (rejection sampling)."""
    firsts, seconds = [], []
    found = 0
    while found < count:
        a = rng.integers(0, n, size=2 * (count - found) + 8)
        b = rng.integers(0, n, size=len(a))
        ok = np.abs(a - b) >= min_separation
        firsts.append(a[ok])
        seconds.append(b[ok])
        found += int(ok.sum())
    return np.concatenate(firsts)[:count], np.concatenate(seconds)[:count]
