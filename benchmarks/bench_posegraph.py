"""Pose-graph optimisation time on every shared benchmark graph: batch LM vs iSAM2.

Batch: one Levenberg-Marquardt run from the file's initial poses (or composed odometry).
iSAM2: the graph fed one vertex at a time with the edges it closes, each vertex
predicted from its parent's current estimate (as online), GTSAM's default
relinearisation (threshold 0.1, every 10 updates), then up to 3 extra updates; Cholesky,
redone with QR where Cholesky finds the system indeterminate (the time includes both). The
iSAM2 total is the cost of having an up-to-date estimate after *every* vertex; the batch
column is one solve at the end. Also shown: GTSAM's own ``readG2o`` + LM on the same file
(the baseline for slamfront's reader and factor building), and ATE where ground truth
exists.

Run: .venv/bin/python benchmarks/bench_posegraph.py [name ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import gtsam
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.core.alignment import ate_rmse  # noqa: E402
from slamfront.data import data_root  # noqa: E402
from slamfront.errors import SlamfrontError  # noqa: E402
from slamfront.posegraph.io import read_graph, read_ground_truth  # noqa: E402
from slamfront.posegraph.solver import SolverOptions, optimize  # noqa: E402

GRAPHS = {
    # name: (graph file, ground truth or None)
    "intel": ("se-sync/intel.g2o", None),
    "INTEL (slambook)": ("slambook/INTEL.g2o", None),
    "MIT": ("se-sync/MIT.g2o", None),
    "CSAIL": ("se-sync/CSAIL.g2o", None),
    "M3500": ("slambook/M3500.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "M3500a": ("slambook/M3500a.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "M3500b": ("slambook/M3500b.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "M3500c": ("slambook/M3500c.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "manhattan (se-sync)": ("se-sync/manhattan.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "manhattanOlson3500 (iSAM)": ("isam/manhattanOlson3500.txt", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "ais2klinik": ("se-sync/ais2klinik.g2o", None),
    "kitti_00": ("se-sync/kitti_00.g2o", None),
    "kitti_02": ("se-sync/kitti_02.g2o", None),
    "kitti_05": ("se-sync/kitti_05.g2o", None),
    "city10000": ("se-sync/city10000.g2o", "gtsam/ISAM2_GT_city10000.txt"),
    "city10000 (iSAM)": ("isam/city10000.txt", "gtsam/ISAM2_GT_city10000.txt"),
    "sphere400 (iSAM)": ("isam/sphere400.txt", None),
    "sphere2500": ("se-sync/sphere2500.g2o", "gtsam/sphere2500_groundtruth.txt"),
    "sphere2500 (iSAM)": ("isam/sphere2500.txt", "gtsam/sphere2500_groundtruth.txt"),
    "sphere (slambook)": ("slambook/sphere_slambook2.g2o", None),
    "sphere_bignoise_vertex3": ("se-sync/sphere_bignoise_vertex3.g2o", None),
    "torus3D": ("se-sync/torus3D.g2o", None),
    "torus10000 (iSAM)": ("isam/torus10000.txt", None),
    "parking-garage": ("se-sync/parking-garage.g2o", None),
    "cubicle": ("se-sync/cubicle.g2o", None),
    "smallGrid3D": ("se-sync/smallGrid3D.g2o", None),
    "tinyGrid3D": ("se-sync/tinyGrid3D.g2o", None),
}


def gtsam_reference(path: Path, is3d: bool) -> float:
    """Seconds for GTSAM's own readG2o + prior + LM (baseline for our reader and builder)."""
    start = time.perf_counter()
    factors, values = gtsam.readG2o(str(path), is3d)
    first = int(min(values.keys()))
    if is3d:
        factors.add(gtsam.PriorFactorPose3(first, values.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
    else:
        factors.add(gtsam.PriorFactorPose2(first, values.atPose2(first), gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)))
    gtsam.LevenbergMarquardtOptimizer(factors, values, gtsam.LevenbergMarquardtParams()).optimize()
    return time.perf_counter() - start


def measure(name: str, root: Path) -> list[object]:
    graph_file, truth_file = GRAPHS[name]
    start = time.perf_counter()
    try:
        graph = read_graph(root / graph_file).parsed.graph
    except SlamfrontError as exc:  # e.g. cubicle.g2o: non-positive-definite information matrices
        return [name, "-", "-", "-", f"rejected: {str(exc).split('/')[-1][:90]}", *["-"] * 10]
    read_seconds = time.perf_counter() - start
    d = graph.dim
    batch = optimize(graph, SolverOptions())
    reference = ratio = "-"
    if graph_file.endswith(".g2o") and graph.poses is not None:  # readG2o needs VERTEX lines
        seconds = gtsam_reference(root / graph_file, d == 3)
        reference, ratio = f"{seconds:.3g}", f"{(read_seconds + batch.seconds) / seconds:.3g}"
    truth = read_ground_truth(root / truth_file, graph) if truth_file is not None else None
    row: list[object] = [
        name, f"{d}-D", graph.n_vertices, graph.n_edges, read_seconds,
        batch.seconds, f"{batch.iterations}{'' if batch.converged else ' (not converged)'}", reference, ratio,
    ]
    try:
        incremental = optimize(graph, SolverOptions(mode="isam2"))
    except SlamfrontError as exc:  # a graph GTSAM cannot solve is a result too
        ate = "-" if truth is None else f"{ate_rmse(batch.initial[:, :d, d], truth):.3g} / {ate_rmse(batch.poses[:, :d, d], truth):.3g} / -"
        return row + [f"failed: {str(exc).split(': ', 1)[-1][:60]}", "-", "-", "-", "-", ate]
    difference = float(np.abs(incremental.poses[:, :d, d] - batch.poses[:, :d, d]).max())
    ate = "-"
    if truth is not None:
        ate = (f"{ate_rmse(batch.initial[:, :d, d], truth):.3g} / {ate_rmse(batch.poses[:, :d, d], truth):.3g} / "
               f"{ate_rmse(incremental.poses[:, :d, d], truth):.3g}")
    return row + [
        incremental.seconds, incremental.factorization, incremental.seconds / batch.seconds, incremental.cost_after / batch.cost_after,
        difference, ate,
    ]


def main() -> None:
    names = sys.argv[1:] or list(GRAPHS)
    root = data_root() / "posegraphs"
    rows = [measure(name, root) for name in tqdm(names, desc="pose graphs", unit="graph")]
    headers = [
        "graph", "dim", "vertices", "edges", "read s", "batch LM s", "LM iterations", "GTSAM readG2o+LM s",
        "(read + batch) / GTSAM",
        "iSAM2 s", "iSAM2 solver", "iSAM2 / batch time", "iSAM2 / batch cost", "max position diff m", "ATE m: initial / batch / iSAM2",
    ]
    body = "\n\n".join([
        __doc__.split("Run:")[0].strip(),
        table(headers, rows),
    ])
    publish("posegraph", "Pose-graph optimisation: batch vs iSAM2", body)


if __name__ == "__main__":
    main()
