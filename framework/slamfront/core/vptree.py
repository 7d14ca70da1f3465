"""Exact k-nearest-neighbour search in a metric space with a vantage-point tree.

A VP-tree (Yianilos 1993, "Data structures and algorithms for nearest neighbor search
in general metric spaces") splits its points by their distance to a *vantage point*:
those closer than the median distance ``mu`` go inside, the others outside. A query at
distance ``d`` from the vantage point can then skip a whole side by the triangle
inequality. Each node keeps the exact range of distances of its two sides to the
vantage point (Yianilos' "enhanced" bounds), so a side is skipped when

    max(lo - d, d - hi, 0) > tau

where ``tau`` is the k-th best distance found so far. The comparison is strict and
``tau`` gets a relative slack for float32 rounding, so ties are always explored and the
answer is exactly what brute force returns, ordered by (distance, id).

The tree grows one point at a time (places are added as a traversal is driven): a new
point descends to a leaf bucket, a full bucket splits into a node, and a subtree that
becomes lopsided is rebuilt balanced (as a scapegoat tree does), so depth stays
logarithmic whatever the insertion order. Bulk :meth:`VPTree.extend` on an empty tree
builds it balanced in one go.

Points are identified by their insertion order (0, 1, 2, ...). A search can be limited
to an id range, which keeps it exact: ids outside the range are never returned.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from slamfront.core.buffers import GrowingRows
from slamfront.core.distances import Metric, k_nearest, smallest, to_one
from slamfront.core.errors import CoreError

_SLACK = 1e-5
"""Relative slack on the pruning bound: float32 sums may break the triangle inequality by a few ulps."""


@dataclass
class _Node:
    """A leaf (``ids`` set) or an internal node (``vantage`` set)."""

    ids: list[int] | None = None
    vantage: int = -1
    mu: float = 0.0
    inside: _Node | None = None
    outside: _Node | None = None
    in_bounds: list[float] = field(default_factory=lambda: [np.inf, -np.inf])
    out_bounds: list[float] = field(default_factory=lambda: [np.inf, -np.inf])
    size: int = 0
    id_min: int = np.iinfo(np.int64).max
    id_max: int = -1

    def note_id(self, point: int) -> None:
        self.size += 1
        self.id_min = min(self.id_min, point)
        self.id_max = max(self.id_max, point)


class VPTree:
    """An incremental vantage-point tree over ``(D,)`` float32 vectors.

    :param dim: vector length D.
    :param metric: a true metric from :mod:`slamfront.core.distances` (``l1``, ``l2``
        or ``hamming``; ``cosine`` is not a metric and is refused).
    :param leaf_size: points per leaf bucket (searched by one vectorised distance call).
    :param balance: a subtree is rebuilt when one side holds more than this fraction
        of it (0.5 < balance < 1).
    :param seed: seeds the choice of vantage points (results never depend on it).
    """

    def __init__(
        self, dim: int, metric: Metric = "l1", leaf_size: int = 32, balance: float = 0.8, seed: int = 0
    ) -> None:
        if metric == "cosine":
            raise CoreError("a VP-tree needs a metric; cosine distance breaks the triangle inequality")
        if leaf_size < 2 or not 0.5 < balance < 1.0:
            raise CoreError("leaf_size must be >= 2 and balance in (0.5, 1)")
        self.metric: Metric = metric
        self.leaf_size = leaf_size
        self.balance = balance
        self._rows = GrowingRows(dim, dtype=np.uint8 if metric == "hamming" else np.float32)
        self._root = _Node(ids=[])
        self._rng = np.random.default_rng(seed)
        self.distance_calls = 0
        """Vectors compared by searches so far (a measure of how much the tree prunes)."""

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def vectors(self) -> np.ndarray:
        """(N, D) the stored points, by id (a view)."""
        return self._rows.view

    # --- building ---------------------------------------------------------------------

    def add(self, vector: np.ndarray) -> int:
        """Insert one point; returns its id."""
        point = self._rows.append(self._checked(vector))
        path: list[_Node] = []
        node = self._root
        while node.ids is None:
            path.append(node)
            node.note_id(point)
            d = self._distance(point, node.vantage)
            bounds = node.in_bounds if d < node.mu else node.out_bounds
            bounds[0], bounds[1] = min(bounds[0], d), max(bounds[1], d)
            node = node.inside if d < node.mu else node.outside  # type: ignore[assignment]
        node.ids.append(point)
        node.note_id(point)
        if len(node.ids) > self.leaf_size:
            self._replace(path, node, self._build(node.ids))
        self._rebalance(path)
        return point

    def extend(self, vectors: np.ndarray) -> np.ndarray:
        """Insert many points; on an empty tree the result is built balanced at once."""
        vectors = np.atleast_2d(vectors)
        if len(self) == 0 and len(vectors):
            ids = [self._rows.append(self._checked(v)) for v in vectors]
            self._root = self._build(ids)
            return np.asarray(ids, dtype=np.int64)
        return np.asarray([self.add(v) for v in vectors], dtype=np.int64)

    def _distance(self, a: int, b: int) -> float:
        rows = self._rows.view
        return float(_row_distances(self.metric)(rows[a], rows[b : b + 1])[0])

    def _checked(self, vector: np.ndarray) -> np.ndarray:
        vector = np.asarray(vector)
        if vector.shape != (self._rows.view.shape[1],):
            raise CoreError(f"vector has shape {vector.shape}, the tree holds ({self._rows.view.shape[1]},)")
        return vector

    def _build(self, ids: list[int]) -> _Node:
        """A balanced subtree over ``ids``."""
        node = _Node()
        for point in ids:
            node.note_id(point)
        if len(ids) <= self.leaf_size:
            node.ids = list(ids)
            return node
        ids_array = np.asarray(ids, dtype=np.int64)
        vantage = int(ids_array[self._rng.integers(len(ids_array))])
        rest = ids_array[ids_array != vantage]
        d = to_one(self._rows.view[vantage], self._rows.view[rest], self.metric).astype(np.float64)
        # split at the median by rank, so equal distances (duplicates) still halve the set;
        # searches rely only on the exact distance ranges of each side, not on mu
        order = np.argsort(d, kind="stable")
        inside = np.zeros(len(rest), dtype=bool)
        inside[order[: len(rest) // 2]] = True
        mu = float(d[order[len(rest) // 2]])
        node.vantage, node.mu = vantage, mu
        node.in_bounds = [float(d[inside].min()), float(d[inside].max())] if inside.any() else [np.inf, -np.inf]
        node.out_bounds = [float(d[~inside].min()), float(d[~inside].max())]
        node.inside = self._build(rest[inside].tolist())
        node.outside = self._build(rest[~inside].tolist())
        return node

    def _replace(self, path: list[_Node], old: _Node, new: _Node) -> None:
        if not path:
            self._root = new
        elif path[-1].inside is old:
            path[-1].inside = new
        else:
            path[-1].outside = new

    def _rebalance(self, path: list[_Node]) -> None:
        """Rebuild the highest node on the insertion path whose sides became lopsided."""
        for depth, node in enumerate(path):
            sides = (node.inside.size if node.inside else 0, node.outside.size if node.outside else 0)
            if node.size > 4 * self.leaf_size and max(sides) > self.balance * node.size:
                self._replace(path[:depth], node, self._build(self._collect(node)))
                return

    def _collect(self, node: _Node) -> list[int]:
        out: list[int] = []
        stack = [node]
        while stack:
            current = stack.pop()
            if current.ids is not None:
                out.extend(current.ids)
            else:
                out.append(current.vantage)
                stack.extend(c for c in (current.inside, current.outside) if c is not None)
        return out

    def depth(self) -> int:
        """Longest root-to-leaf path (for tests of balance)."""
        best, stack = 0, [(self._root, 1)]
        while stack:
            node, level = stack.pop()
            best = max(best, level)
            if node.ids is None:
                stack.extend((c, level + 1) for c in (node.inside, node.outside) if c is not None)
        return best

    # --- searching --------------------------------------------------------------------

    def knn(self, query: np.ndarray, k: int, lo: int = 0, hi: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest points to ``query`` with ``lo <= id <= hi``.

        :returns: ``(ids, distances)``, (<= k,) int64 and float32, ordered by distance
            then id: exactly what sorting all brute-force distances (stable) returns.
        """
        if k < 1:
            raise CoreError("k must be >= 1")
        query = self._checked(query)
        hi = len(self) - 1 if hi is None else min(hi, len(self) - 1)
        best: list[tuple[float, int]] = []  # max-heap of (-distance, -id): the worst on top

        def tau() -> float:
            return -best[0][0] if len(best) == k else np.inf

        def offer(point: int, distance: float) -> None:
            item = (-distance, -point)
            if len(best) < k:
                heapq.heappush(best, item)
            elif item > best[0]:  # closer, or as close with a smaller id
                heapq.heapreplace(best, item)

        def lower_bound(d: float, bounds: list[float]) -> float:
            return max(bounds[0] - d, d - bounds[1], 0.0)

        rows = self._rows.view
        distance = _row_distances(self.metric)
        stack: list[tuple[_Node, float]] = [(self._root, 0.0)]
        while stack:
            node, bound = stack.pop()
            if node.size == 0 or node.id_max < lo or node.id_min > hi or bound > tau() * (1 + _SLACK):
                continue
            if node.ids is not None:
                ids = node.ids
                if node.id_min < lo or node.id_max > hi:
                    ids = [i for i in ids if lo <= i <= hi]
                if ids:
                    self.distance_calls += len(ids)
                    dists = distance(query, rows[ids])
                    limit = tau()
                    for j in np.flatnonzero(dists <= limit).tolist() if limit < np.inf else range(len(ids)):
                        offer(ids[j], float(dists[j]))
                continue
            self.distance_calls += 1
            d = float(distance(query, rows[node.vantage : node.vantage + 1])[0])
            if lo <= node.vantage <= hi:
                offer(node.vantage, d)
            b_in, b_out = lower_bound(d, node.in_bounds), lower_bound(d, node.out_bounds)
            # push the farther side first so the nearer one is searched first
            if b_in <= b_out:
                stack.append((node.outside, b_out))  # type: ignore[arg-type]
                stack.append((node.inside, b_in))  # type: ignore[arg-type]
            else:
                stack.append((node.inside, b_in))  # type: ignore[arg-type]
                stack.append((node.outside, b_out))  # type: ignore[arg-type]
        ordered = sorted((-neg_d, -neg_id) for neg_d, neg_id in best)
        return (
            np.asarray([p for _, p in ordered], dtype=np.int64),
            np.asarray([d for d, _ in ordered], dtype=np.float32),
        )


def _row_distances(metric: Metric):  # type: ignore[no-untyped-def]
    """A lean (query, rows) -> (M,) distance for the hot loop; l1 and hamming give the same
    float32 bits as :func:`~slamfront.core.distances.to_one` (same per-row reduction)."""
    if metric == "l1":
        return lambda q, rows: np.abs(rows - q).sum(-1, dtype=np.float32)
    return lambda q, rows: to_one(q, rows, metric)


def brute_force_knn(
    query: np.ndarray, rows: np.ndarray, k: int, metric: Metric = "l1", lo: int = 0, hi: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The reference answer :meth:`VPTree.knn` must equal: all distances, stably ranked.

    float32 L1 ranks through :func:`k_nearest` (a vectorised bound, re-ranked near the cut
    with the exact distances: the same order) and computes the exact distances of the k
    chosen only; they are the bits :func:`to_one` gives for those rows.
    """
    hi = len(rows) - 1 if hi is None else min(hi, len(rows) - 1)
    window = rows[lo : hi + 1]
    if metric == "l1" and query.dtype == window.dtype == np.float32 and 0 < k < len(window):
        order = k_nearest(query, window, k, metric)[0]
        return (order + lo).astype(np.int64), to_one(query, window[order], metric).astype(np.float32)
    distances = to_one(query, window, metric)
    order = smallest(distances, k)
    return (order + lo).astype(np.int64), distances[order].astype(np.float32)


VPTREE_MIN_PLACES = 10_000
"""Below this many points brute force wins whatever the data (benchmarks/results/vptree.md:
the tree is 4-8x slower at 1,000 points even at intrinsic dimension 2)."""

VPTREE_MAX_FRACTION = 0.1
"""The tree pays when a search computes at most this share of the distances brute force
computes (benchmarks/results/vptree.md: at 2.5 % it is 2-3x faster than brute force,
at 96 % -- Nordland's RST-SHelo -- 6x slower: each of its distances costs more)."""


def vptree_pays(
    rows: np.ndarray, metric: Metric = "l1", leaf_size: int = 32, k: int = 10, probes: int = 20
) -> VPTree | None:
    """A VP-tree over ``rows`` (M, D) if it beats brute force on them, else None.

    The rule is measured on the data, not guessed: with at least
    :data:`VPTREE_MIN_PLACES` rows, a tree is built and ``probes`` evenly spaced rows are
    searched (``k`` nearest); it is kept when it computed at most
    :data:`VPTREE_MAX_FRACTION` of the distances brute force would. Counting distances
    (not timing) keeps the choice deterministic; the answers are the same either way.
    """
    if len(rows) < VPTREE_MIN_PLACES:
        return None
    tree = VPTree(rows.shape[1], metric, leaf_size=leaf_size)
    tree.extend(rows)
    picked = np.unique(np.linspace(0, len(rows) - 1, probes).astype(int))
    tree.distance_calls = 0
    for row in picked:
        tree.knn(rows[row], k)
    return tree if tree.distance_calls <= VPTREE_MAX_FRACTION * len(picked) * len(rows) else None
