"""Lines through a table of query-to-map distances: the compiled path gives the NumPy
reference's bits and distance counts (the oracle), call after call of a cache that moves on."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.distances import rowwise
from slamfront.core.line_costs import DescriptorRows, PairDistances


def _pair(vectors: np.ndarray, query_rows: np.ndarray, map_rows: np.ndarray, keep: int,
          compiled: bool) -> PairDistances:
    def compute(t: np.ndarray, m: np.ndarray) -> np.ndarray:
        return rowwise(vectors[query_rows[t]], vectors[map_rows[m]], "l1")

    rows = DescriptorRows(vectors, query_rows, map_rows, "l1")
    return PairDistances(compute, keep, descriptors=(lambda: rows) if compiled else None)


@pytest.mark.parametrize(("dims", "dtype", "seed"), [(7, np.float32, 0), (100, np.float32, 1), (300, np.float32, 2),
                                                      (1152, np.float32, 3), (61, np.uint8, 4)])
def test_compiled_line_costs_equal_the_numpy_reference(dims: int, dtype: type, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_map, n_query = 150, 120
    scale = 255 if dtype == np.uint8 else 1.0
    vectors = (rng.random((n_map + n_query, dims)) * scale).astype(dtype)
    if dtype == np.float32:  # distances over 30 orders of magnitude: a float64 sum of them depends on its order
        vectors *= (10.0 ** rng.uniform(-15, 15, (len(vectors), 1))).astype(np.float32)
    map_rows = rng.permutation(n_map + n_query)[:n_map].astype(np.int64)
    query_rows = rng.integers(0, n_map + n_query, n_query).astype(np.int64)
    keep = 24  # small: windows reuse and clear rows, and a long window makes the table grow
    reference = _pair(vectors, query_rows, map_rows, keep, compiled=False)
    compiled = _pair(vectors, query_rows, map_rows, keep, compiled=True)
    informative = rng.random(n_map) > 0.1
    end = 10
    for call in range(60):
        end = min(n_query - 1, end + int(rng.integers(0, 4)))
        length = int(rng.integers(1, 40 if call % 15 else 70))
        rows = np.arange(max(0, end - length + 1), end + 1, dtype=np.int64)
        rows = rows[rng.random(len(rows)) > 0.15] if len(rows) > 2 else rows
        speeds = np.round(rng.uniform(-2.5, 2.5, int(rng.integers(1, 6))), 3)
        shifts = np.arange(-int(rng.integers(0, 4)), int(rng.integers(0, 4)) + 1, dtype=np.int64)
        anchor_query, anchor_map = int(rows[0]) if len(rows) else end, int(rng.integers(-20, n_map + 20))
        n_usable = int(rng.integers(n_map // 2, n_map + 1))
        flags = None if call % 7 == 0 else informative[:n_usable]
        need = int(rng.integers(1, max(2, len(rows) + 1)))
        args = (rows, anchor_query, anchor_map, shifts, speeds, n_usable, flags, need)
        want_costs, want_counts = reference.line_costs(*args)
        got_costs, got_counts = compiled.line_costs(*args)
        assert np.array_equal(got_counts, want_counts)
        assert np.array_equal(got_costs, want_costs), call  # same bits, inf where too few pairs
        assert compiled.computed == reference.computed  # the same distances computed (and counted)
    assert reference.computed > 0
    assert compiled._keep == reference._keep > keep  # a window spanned more than the table: both grew it


@pytest.mark.parametrize(("compiled", "seed"), [(True, 0), (True, 1), (False, 2)])
def test_best_lines_of_many_anchors_equal_line_costs_anchor_by_anchor(compiled: bool, seed: int) -> None:
    """One call for many anchors: each anchor's lowest line as ``costs.argmin()`` picks it
    (-1 when no line has a finite cost), the same bits and the same distances computed as
    line_costs called anchor by anchor, through table resizes."""
    rng = np.random.default_rng(seed)
    n_map, n_query, dims = 120, 100, 40
    vectors = rng.random((n_map + n_query, dims)).astype(np.float32)
    map_rows, query_rows = np.arange(n_map, dtype=np.int64), np.arange(n_map, n_map + n_query, dtype=np.int64)
    one = _pair(vectors, query_rows, map_rows, 8, compiled)
    many = _pair(vectors, query_rows, map_rows, 8, compiled)
    informative = rng.random(n_map) > 0.1
    shifts = np.arange(-2, 3, dtype=np.int64)
    for call in range(25):
        end = int(rng.integers(20, n_query))
        rows = np.arange(end - int(rng.integers(3, 30 if call % 5 else 60)), end + 1, dtype=np.int64)
        speeds = np.round(rng.uniform(-1.5, 1.5, int(rng.integers(1, 5))), 3)
        anchors_t = rng.integers(rows[0], rows[-1] + 1, int(rng.integers(1, 12)))
        anchors_m = rng.integers(-30, n_map + 30, len(anchors_t))  # some lines fall outside the map
        need = int(rng.integers(1, len(rows) + 1))
        best, cost, count = many.best_lines(rows, anchors_t, anchors_m, shifts, speeds, n_map, informative, need)
        for a in range(len(anchors_t)):
            costs, counts = one.line_costs(rows, int(anchors_t[a]), int(anchors_m[a]), shifts, speeds, n_map,
                                           informative, need)
            lowest = int(costs.argmin())
            if not np.isfinite(costs).any():
                assert best[a] == -1 and cost[a] == np.inf and count[a] == 0
            else:
                assert best[a] == lowest and cost[a] == costs.flat[lowest] and count[a] == counts.flat[lowest]
        assert many.computed == one.computed
    assert (many._keep, many.computed) == (one._keep, one.computed) and many._keep > 8  # both tables grew


@pytest.mark.parametrize("dims", [1, 7, 8, 9, 128, 129, 160, 300, 512, 576, 1024, 1152, 1153, 2304, 8192, 16384])
def test_the_compiled_distance_has_rowwise_bits(dims: int) -> None:
    from slamfront.core.line_kernels import pairwise_l1

    rng = np.random.default_rng(dims)
    a = (rng.random((40, dims)) * rng.choice([1e-3, 1.0, 1e3], (40, 1))).astype(np.float32)
    b = rng.random((40, dims)).astype(np.float32)
    frames, partial = np.empty((3, 64), dtype=np.int64), np.empty(64, dtype=np.float32)
    got = np.array([pairwise_l1(x, y, frames, partial) for x, y in zip(a, b)], dtype=np.float32)
    assert np.array_equal(got, rowwise(a, b, "l1"))
    # uint8 descriptors: widened to float32 first, as rowwise does
    a8, b8 = rng.integers(0, 256, (40, dims), dtype=np.uint8), rng.integers(0, 256, (40, dims), dtype=np.uint8)
    got = np.array([pairwise_l1(x, y, frames, partial) for x, y in zip(a8, b8)], dtype=np.float32)
    assert np.array_equal(got, rowwise(a8, b8, "l1"))


def test_other_metrics_go_through_the_compute_callable() -> None:
    vectors = np.random.default_rng(5).integers(0, 256, (30, 32), dtype=np.uint8)
    assert not DescriptorRows(vectors, np.arange(10), np.arange(10, 30), "hamming").compiled
    assert not DescriptorRows(vectors.astype(np.float64), np.arange(10), np.arange(10, 30), "l1").compiled
    assert DescriptorRows(vectors, np.arange(10), np.arange(10, 30), "l1").compiled


def test_the_cone_keeps_the_same_lines_when_each_lookup_makes_only_its_lowest() -> None:
    """``_lines`` makes trajectories of its ``limit`` lowest lines only: the lowest ``limit`` of
    several lookups, stably sorted, are the ones all their lines would give (ties included)."""
    from slamfront_plugins.loop_detectors.hierarchical_frames import _lines

    rng = np.random.default_rng(11)
    query = rng.integers(0, 4, (60, 6)).astype(np.float32)  # few distinct values: many tied costs
    map_vectors = rng.integers(0, 4, (90, 6)).astype(np.float32)
    pairs = PairDistances(lambda t, m: np.abs(query[t] - map_vectors[m]).sum(axis=1), 100)
    rows = np.arange(30, 46)
    lookups = [(40, np.arange(-2, 3), np.round(np.arange(0.4, 2.6, 0.125), 3)),
               (55, np.arange(-1, 2), -np.round(np.arange(0.4, 2.6, 0.125), 3))]
    every = [line for anchor, shifts, speeds in lookups
             for line in _lines(pairs, rows, 30, anchor, shifts, speeds, 90, None, 10**9)]
    for limit in (1, 3, 4, 7):
        kept = [line for anchor, shifts, speeds in lookups
                for line in _lines(pairs, rows, 30, anchor, shifts, speeds, 90, None, limit)]
        assert sorted(kept, key=lambda t: t.cost)[:limit] == sorted(every, key=lambda t: t.cost)[:limit]
        assert min(kept, key=lambda t: t.cost) == min(every, key=lambda t: t.cost)
    assert len({line.cost for line in every}) < len(every)  # ties were there to keep in order
