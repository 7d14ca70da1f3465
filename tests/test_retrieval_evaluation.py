"""The descriptor-retrieval evaluation ranks exactly as the full distance matrix does."""

from __future__ import annotations

import numpy as np

from slamfront.core.distances import pairwise
from slamfront.core.loops import LoopGroundTruth, recall_at_k
from slamfront.evaluation.retrieval import DescriptorRetrieval
from slamfront.messages import Features, FrameInfo


def test_retrieval_curve_is_the_full_matrix_ranking() -> None:
    """A small paired run of RST-SHelo-like vectors (non-negative, unit L1, float32), with
    repeated references and near-ties: the curve equals the one computed the way the
    evaluation did before, a stable sort of every query-reference distance."""
    rng = np.random.default_rng(7)
    n, dims, max_k = 150, 96, 20
    places = rng.random((n, dims)).astype(np.float32) ** 4
    reference = places / places.sum(axis=1, keepdims=True)
    reference[40] = reference[41]  # identical references: ties broken by index
    noisy = np.abs(places * (1 + 0.6 * rng.standard_normal(places.shape))).astype(np.float32)
    query = noisy / noisy.sum(axis=1, keepdims=True)
    query[10] = 0.0  # a featureless query: equal distances to every reference of the same norm
    truth = LoopGroundTruth.band(np.arange(n, 2 * n), np.arange(n), tolerance=1, valid=(0, n - 1))
    watcher = DescriptorRetrieval()
    for frame in range(2 * n):
        traversal, vector = ("reference", reference[frame]) if frame < n else ("query", query[frame - n])
        watcher.observe("frames", FrameInfo(frame, float(frame), traversal, frame % n, "", 64, 32))
        watcher.observe("descriptor", Features(frame=frame, vector=vector, metric="l1"))
    curve, n_queries, n_references = watcher.curve(truth, max_k)  # type: ignore[misc]
    order = np.argsort(pairwise(query, reference, "l1"), axis=1, kind="stable")[:, :max_k]
    want = recall_at_k(np.arange(n, 2 * n), list(order), truth, list(range(1, max_k + 1)))
    assert (n_queries, n_references) == (n, n)
    assert curve.tolist() == [want[k] for k in range(1, max_k + 1)]
    assert 0 < curve[0] < curve[-1] <= 1
