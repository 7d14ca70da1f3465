"""Precision-recall and loop ground truth on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.errors import CoreError
from slamfront.core.loops import LoopGroundTruth, precision_recall, recall_at_k


def test_band_ground_truth_and_correctness() -> None:
    truth = LoopGroundTruth.band(np.array([10, 11, 12]), np.array([0, 5, -1]), tolerance=2, valid=(0, 9))
    assert truth.has_true_match().tolist() == [True, True, False]
    assert truth.matches[truth.indptr[0] : truth.indptr[1]].tolist() == [0, 1, 2]  # clipped at 0
    got = truth.is_correct(np.array([10, 10, 11, 11, 12, 99]), np.array([2, 3, 7, 8, 0, 0]))
    assert got.tolist() == [True, False, True, False, False, False]


def test_band_rejects_mismatched_lengths() -> None:
    with pytest.raises(CoreError, match="3 queries but 2"):
        LoopGroundTruth.band(np.array([1, 2, 3]), np.array([1, 2]), 3)


def test_precision_recall_by_hand() -> None:
    # confidences 0.9 (correct), 0.8 (wrong), 0.7 (correct), no answer; 4 positives
    pr = precision_recall(
        confidence=np.array([0.9, 0.8, 0.7, 0.5]),
        answered=np.array([True, True, True, False]),
        correct=np.array([True, False, True, True]),
        n_positive=4,
    )
    assert pr.thresholds.tolist() == [0.9, 0.8, 0.7]
    assert pr.precision.tolist() == pytest.approx([1.0, 0.5, 2 / 3])
    assert pr.recall.tolist() == pytest.approx([0.25, 0.25, 0.5])
    assert pr.recall_at_100p == pytest.approx(0.25)
    assert pr.threshold_at_100p() == pytest.approx(0.9)
    # average precision: 0.25 * 1 + 0 * 0.5 + 0.25 * 2/3
    assert pr.auc == pytest.approx(0.25 + 0.25 * 2 / 3)


def test_ties_enter_together() -> None:
    pr = precision_recall(np.array([0.5, 0.5]), np.array([True, True]), np.array([True, False]), 2)
    assert pr.recall_at_100p == 0.0  # a threshold of 0.5 accepts both, one of them wrong
    assert len(pr.thresholds) == 1


def test_first_report_wrong_gives_zero_recall_at_full_precision() -> None:
    pr = precision_recall(np.array([0.9, 0.1]), np.array([True, True]), np.array([False, True]), 1)
    assert pr.recall_at_100p == 0.0


def test_recall_at_k() -> None:
    truth = LoopGroundTruth.band(np.array([5, 6]), np.array([0, 1]), tolerance=0)
    got = recall_at_k(np.array([5, 6]), [np.array([3, 0]), np.array([2, 3])], truth, [1, 2])
    assert got == {1: 0.0, 2: 0.5}


def test_batched_correctness_and_recall_at_k_match_a_per_query_check() -> None:
    # is_correct and recall_at_k check all queries in one search; compare with a plain
    # per-pair membership test on random truth (unknown frames, -1 answers, empty rows)
    rng = np.random.default_rng(3)
    queries = np.arange(100, 160)
    rows = [np.unique(rng.integers(0, 90, rng.integers(0, 6))) for _ in queries]
    truth = LoopGroundTruth.from_rows(queries, rows)
    frames = rng.choice(np.r_[queries, 999, 1000], 500)
    matches = rng.integers(-1, 90, 500)
    members = {int(q): set(r.tolist()) for q, r in zip(queries, rows)}
    expected = [m >= 0 and int(m) in members.get(int(f), set()) for f, m in zip(frames, matches)]
    assert truth.is_correct(frames, matches).tolist() == expected
    candidates = [rng.integers(0, 90, rng.integers(0, 12)) for _ in queries]
    positives = [q for q, r in zip(queries, rows) if len(r)]
    for k in (1, 3, 10):
        hits = sum(any(int(c) in members[int(q)] for c in cands[:k]) for q, cands in zip(queries, candidates) if len(members[int(q)]))
        assert recall_at_k(queries, candidates, truth, [k])[k] == pytest.approx(hits / len(positives))
