"""Sequence alignment, place-based ground truth and k-nearest retrieval on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.distances import k_nearest, pairwise
from slamfront.core.errors import CoreError
from slamfront.core.loops import LoopGroundTruth
from slamfront.core.sequences import alignment_costs, best_alignment


def test_alignment_costs_sum_each_diagonal() -> None:
    distances = np.array([[1.0, 0.0, 5.0, 9.0], [7.0, 2.0, 0.0, 1.0]])
    # j = 0: d[0,0] + d[1,1] = 3; j = 1: d[0,1] + d[1,2] = 0; j = 2: d[0,2] + d[1,3] = 6
    assert alignment_costs(distances).tolist() == [3.0, 0.0, 6.0]
    assert best_alignment(distances) == (1, 0.0)
    assert alignment_costs(np.ones((3, 3))).tolist() == [3.0]


def test_alignment_refuses_a_candidate_shorter_than_the_query() -> None:
    with pytest.raises(CoreError, match="shorter"):
        alignment_costs(np.ones((4, 3)))
    with pytest.raises(CoreError, match="n >= 1"):
        alignment_costs(np.ones((0, 3)))


def test_ground_truth_by_place_survives_reordering_and_replacement() -> None:
    # reference stream 0..5 shows places [0, 1, 4, 5, nan, 2]: block moved, one frame foreign
    frames = np.arange(6)
    places = np.array([0, 1, 4, 5, np.nan, 2], dtype=np.float64)
    queries = np.array([10, 11, 12, 13])
    query_places = [np.array([0.0]), np.array([2.0]), np.array([3.0]), np.array([], dtype=np.float64)]
    truth = LoopGroundTruth.from_places(queries, query_places, frames, places, tolerance=1)
    rows = [truth.matches[truth.indptr[i] : truth.indptr[i + 1]].tolist() for i in range(4)]
    assert rows == [[0, 1], [1, 5], [2, 5], []]  # place 3 is in no frame: its neighbours 2 and 4 count
    assert truth.has_true_match().tolist() == [True, True, True, False]
    assert truth.is_correct(np.array([11, 11, 12]), np.array([5, 4, 2])).tolist() == [True, False, True]


def test_ground_truth_by_place_with_several_places_and_fractions() -> None:
    truth = LoopGroundTruth.from_places(
        np.array([7]), [np.array([0.5, 9.0])], np.arange(10), np.arange(10, dtype=np.float64), tolerance=1
    )
    assert truth.matches.tolist() == [0, 1, 8, 9]
    with pytest.raises(CoreError, match="2 queries but 1"):
        LoopGroundTruth.from_places(np.array([1, 2]), [np.array([0.0])], np.arange(3), np.arange(3.0), 1)


def test_k_nearest_is_a_stable_sort_of_all_distances() -> None:
    rows = np.array([[0.0], [2.0], [1.0], [1.0], [5.0]], dtype=np.float32)
    queries = np.array([[1.0], [4.0]], dtype=np.float32)
    assert k_nearest(queries, rows, 3, "l1").tolist() == [[2, 3, 0], [4, 1, 2]]
    assert k_nearest(queries, rows, 10, "l1").shape == (2, 5)


@pytest.mark.parametrize(("dims", "k"), [(1152, 20), (37, 5), (3, 1), (200, 63)])
def test_k_nearest_float32_l1_ranks_as_the_exact_distances(dims: int, k: int) -> None:
    """float32 L1 is ranked by a vectorised kernel and re-ranked near the cut with the
    exact (NumPy pairwise-order) distances: the answer must be the full stable sort's,
    ties, duplicated rows and near-ties included."""
    rng = np.random.default_rng(dims)
    rows = rng.random((300, dims)).astype(np.float32)
    rows /= rows.sum(axis=1, keepdims=True)
    queries = rng.random((41, dims)).astype(np.float32)
    queries /= queries.sum(axis=1, keepdims=True)
    rows[7] = rows[3]  # an exact tie
    queries[2] = rows[11]  # a distance of 0
    queries[5] = rows[20] + np.float32(1e-7)  # near-ties
    rows[21] = rows[20] - np.float32(1e-7)
    want = np.argsort(pairwise(queries, rows, "l1"), axis=1, kind="stable")[:, :k]
    assert np.array_equal(k_nearest(queries, rows, k, "l1"), want)
    grid = rng.integers(0, 3, (60, dims)).astype(np.float32)  # many exact ties
    want = np.argsort(pairwise(grid[:20], grid, "l1"), axis=1, kind="stable")[:, :k]
    assert np.array_equal(k_nearest(grid[:20], grid, k, "l1"), want)
