"""The VP-tree returns exactly what brute force returns, however it was built."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.errors import CoreError
from slamfront.core.vptree import VPTree, brute_force_knn


def _walk(n: int, dim: int, seed: int) -> np.ndarray:
    """Descriptors along a route: a random walk on the simplex (like places of a traversal)."""
    rng = np.random.default_rng(seed)
    x = np.abs(np.cumsum(rng.normal(size=(n, dim)), axis=0) * 0.05 + rng.normal(size=(n, dim)) * 0.02)
    return (x / x.sum(axis=1, keepdims=True)).astype(np.float32)


def _same(tree: VPTree, rows: np.ndarray, query: np.ndarray, k: int, lo: int = 0, hi: int | None = None) -> None:
    got_ids, got_d = tree.knn(query, k, lo, hi)
    want_ids, want_d = brute_force_knn(query, rows, k, tree.metric, lo, hi)
    assert got_ids.tolist() == want_ids.tolist()
    assert np.array_equal(got_d, want_d)


@pytest.mark.parametrize("leaf_size", [2, 8, 32])
def test_incremental_tree_equals_brute_force(leaf_size: int) -> None:
    rows = _walk(1500, 24, seed=leaf_size)
    tree = VPTree(24, "l1", leaf_size=leaf_size)
    queries = _walk(40, 24, seed=100)
    for count, row in enumerate(rows, start=1):
        tree.add(row)
        if count in (1, 7, 100, 1500):  # exact at every size while it grows
            for query in queries[:10]:
                _same(tree, rows[:count], query, 10)
    for query in queries:
        _same(tree, rows, query, 1)
        _same(tree, rows, query, 25)


def test_bulk_build_equals_brute_force_and_is_balanced() -> None:
    rows = _walk(4000, 16, seed=1)
    tree = VPTree(16, leaf_size=16)
    tree.extend(rows)
    assert tree.depth() <= 12  # log2(4000 / 16) + 1 levels, give or take
    for query in _walk(30, 16, seed=2):
        _same(tree, rows, query, 10)


def test_rebalancing_keeps_depth_logarithmic_for_sorted_insertions() -> None:
    rows = np.linspace(0, 1, 3000, dtype=np.float32)[:, None] * np.ones((1, 4), np.float32)
    tree = VPTree(4, leaf_size=8)
    for row in rows:  # points along a line, in order: the worst case for a naive tree
        tree.add(row)
    assert tree.depth() <= 30
    _same(tree, rows, np.full(4, 0.5, np.float32), 7)


def test_id_range_restricts_the_answer_exactly() -> None:
    rows = _walk(800, 8, seed=3)
    tree = VPTree(8, leaf_size=4)
    tree.extend(rows)
    for query in _walk(20, 8, seed=4):
        _same(tree, rows, query, 10, lo=4, hi=300)
        _same(tree, rows, query, 10, lo=790)
    assert tree.knn(rows[0], 5, lo=900)[0].size == 0


def test_duplicates_and_ties_come_back_in_id_order() -> None:
    rows = np.zeros((300, 6), dtype=np.float32)
    rows[::5] = 1.0  # many identical points: every distance ties
    tree = VPTree(6, leaf_size=4)
    for row in rows:
        tree.add(row)
    _same(tree, rows, np.zeros(6, np.float32), 50)
    _same(tree, rows, np.ones(6, np.float32), 70)


def test_hamming_distance_on_binary_descriptors() -> None:
    rng = np.random.default_rng(5)
    rows = rng.integers(0, 256, size=(600, 8), dtype=np.uint8)
    tree = VPTree(8, "hamming", leaf_size=8)
    tree.extend(rows[:300])
    for row in rows[300:]:
        tree.add(row)
    for query in rng.integers(0, 256, size=(15, 8), dtype=np.uint8):
        _same(tree, rows, query, 10)


def test_it_prunes_on_low_dimensional_data() -> None:
    rows = _walk(5000, 3, seed=6)
    tree = VPTree(3, leaf_size=16)
    tree.extend(rows)
    for query in _walk(50, 3, seed=7):
        tree.knn(query, 10)
    assert tree.distance_calls / 50 < 0.25 * len(rows)


def test_bad_use_is_refused() -> None:
    with pytest.raises(CoreError, match="metric"):
        VPTree(4, "cosine")
    tree = VPTree(4)
    with pytest.raises(CoreError, match="shape"):
        tree.add(np.zeros(5, np.float32))
    with pytest.raises(CoreError, match="k must be"):
        tree.knn(np.zeros(4, np.float32), 0)
    assert tree.knn(np.zeros(4, np.float32), 3)[0].size == 0  # empty tree: nothing
