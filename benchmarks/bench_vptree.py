"""Place-map search: exact kNN with the incremental VP-tree vs brute force, 10^3 .. 10^6 places.

Synthetic place descriptors (64 values, unit L1 like RST-SHelo) lie on a smooth manifold
of intrinsic dimension d inside the 64-D space: d = 2 is a route through a city seen
from a road network, d = 8 is closer to what an appearance descriptor spans. Also one
row of real data: the 3,576 Nordland summer RST-SHelo descriptors queried with winter.
Times are medians over the queries, k = 10, L1. The baseline is a chunked NumPy brute
force with ``argpartition``; the tree's answers equal a stable sort of all distances
(checked on the first 10 queries of every row, and against the baseline on all).

Run: .venv/bin/python benchmarks/bench_vptree.py [--max-places 1000000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import peak_rss_mb, publish, table  # noqa: E402

from slamfront.core.vptree import VPTree, brute_force_knn  # noqa: E402

DIM = 64
K = 10


def manifold(n: int, intrinsic: int, seed: int) -> np.ndarray:
    """(n, DIM) unit-L1 descriptors on a smooth ``intrinsic``-dimensional manifold."""
    rng = np.random.default_rng(12345)  # the same embedding for places and queries
    weights = rng.normal(0, 3.0, (intrinsic, DIM))
    phase = rng.uniform(0, 2 * np.pi, DIM)
    latent = np.random.default_rng(seed).random((n, intrinsic))
    out = np.empty((n, DIM), dtype=np.float32)
    for start in range(0, n, 100_000):
        block = np.abs(np.cos(latent[start : start + 100_000] @ weights + phase)) + 0.05
        out[start : start + 100_000] = block / block.sum(axis=1, keepdims=True)
    return out


def brute_force(query: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """The baseline: every L1 distance (in cache-sized chunks), then the k smallest (argpartition)."""
    distances = np.empty(len(rows), dtype=np.float32)
    for start in range(0, len(rows), 65_536):
        distances[start : start + 65_536] = np.abs(rows[start : start + 65_536] - query).sum(axis=1)
    nearest = np.argpartition(distances, k - 1)[:k] if len(rows) > k else np.arange(len(rows))
    return nearest[np.lexsort((nearest, distances[nearest]))]


def measure(rows: np.ndarray, queries: np.ndarray, incremental: bool) -> list[object]:
    tree = VPTree(rows.shape[1], "l1", leaf_size=32)
    start = time.perf_counter()
    if incremental:
        for row in rows:
            tree.add(row)
    else:
        tree.extend(rows)
    build = time.perf_counter() - start
    tree_ms, brute_ms, visited = [], [], []
    for number, query in enumerate(queries):
        calls = tree.distance_calls
        start = time.perf_counter()
        ids, distances = tree.knn(query, K)
        tree_ms.append((time.perf_counter() - start) * 1e3)
        visited.append((tree.distance_calls - calls) / len(rows))
        start = time.perf_counter()
        baseline = brute_force(query, rows, K)
        brute_ms.append((time.perf_counter() - start) * 1e3)
        if number < 10:  # exactness against the reference (a stable sort of all distances)
            want_ids, want_distances = brute_force_knn(query, rows, K)
            if ids.tolist() != want_ids.tolist() or not np.array_equal(distances, want_distances):
                raise AssertionError("the VP-tree disagreed with brute force")
        if set(baseline.tolist()) != set(ids.tolist()) and len(set(distances.tolist())) == K:
            raise AssertionError("the baseline disagreed with the VP-tree")
    tree_median, brute_median = float(np.median(tree_ms)), float(np.median(brute_ms))
    return [
        len(rows), "incremental" if incremental else "bulk", build, build / len(rows) * 1e6,
        tree_median, float(np.percentile(tree_ms, 99)), brute_median, brute_median / tree_median,
        float(np.median(visited)),
    ]


def nordland_row() -> list[object] | None:
    import cv2

    from slamfront.data import data_root
    from slamfront_plugins.descriptors.rst_shelo import RstShelo

    folder = data_root() / "nordland"
    if not folder.is_dir():
        return None
    describe = RstShelo().describe
    names = sorted(p.name for p in (folder / "summer").glob("*.png"))
    rows = np.stack([describe(cv2.imread(str(folder / "summer" / n), cv2.IMREAD_GRAYSCALE)) for n in names])
    queries = np.stack([describe(cv2.imread(str(folder / "winter" / n), cv2.IMREAD_GRAYSCALE)) for n in names[::18]])
    return ["Nordland RST-SHelo (288-D, real)", *measure(rows, queries, incremental=True)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-places", type=int, default=1_000_000)
    args = parser.parse_args()
    headers = ["descriptors", "places", "built", "build s", "us/place", "VP-tree ms (median)", "VP-tree ms (p99)",
               "brute force ms", "speed-up", "fraction compared"]
    results = []
    for incremental in (True, False):  # untimed: the first build in a process pays the kernels' compilation
        measure(manifold(200, 2, seed=3), manifold(3, 2, seed=4), incremental)
    for intrinsic in (2, 8):
        for n in (1_000, 10_000, 100_000, 1_000_000):
            if n > args.max_places:
                continue
            rows = manifold(n, intrinsic, seed=1)
            queries = manifold(100 if n < 1_000_000 else 30, intrinsic, seed=2)
            modes = (True, False) if n <= 10_000 else (False,)
            for incremental in modes:
                row = [f"synthetic, d = {intrinsic}", *measure(rows, queries, incremental)]
                results.append(row)
                print(table(headers, [row]).splitlines()[-1], flush=True)
            del rows
    real = nordland_row()
    if real is not None:
        results.append(real)
    body = (
        f"Exact k = {K} nearest neighbours under L1 among place representatives; queries are new points of "
        "the same distribution. `fraction compared` is the share of stored places whose distance the tree "
        "computed (brute force: 1). The tree's answers were checked equal to brute force. One untimed build and "
        "search first (compilation).\n\n"
        + table(headers, results)
        + f"\n\nPeak memory: {peak_rss_mb():.0f} MB.\n"
    )
    publish("vptree", "VP-tree vs brute-force place search", body)


if __name__ == "__main__":
    main()
