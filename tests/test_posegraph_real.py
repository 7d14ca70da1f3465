"""Pose-graph optimisation on the classic benchmarks in ../shared/data/posegraphs."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from slamfront.core.alignment import ate_rmse
from slamfront.core.posegraph import random_false_closures, subgraph
from slamfront.errors import DataError
from slamfront.posegraph.io import read_graph, read_ground_truth
from slamfront.posegraph.solver import SolverOptions, optimize

GRAPHS = {
    # graph, ground truth (None: the benchmark has none)
    "M3500": ("slambook/M3500.g2o", "isam/groundtruth/manhattanOlson3500_groundtruth.txt"),
    "intel": ("se-sync/intel.g2o", None),
    "sphere2500": ("se-sync/sphere2500.g2o", "gtsam/sphere2500_groundtruth.txt"),
    "city10000": ("se-sync/city10000.g2o", "gtsam/ISAM2_GT_city10000.txt"),
}


@pytest.fixture(scope="module")
def posegraphs(shared_data: Path) -> Path:
    return shared_data / "posegraphs"


@pytest.mark.parametrize("name", list(GRAPHS))
def test_benchmark_converges_and_beats_the_initial_ate(name: str, posegraphs: Path) -> None:
    graph_file, truth_file = GRAPHS[name]
    graph = read_graph(posegraphs / graph_file).parsed.graph
    result = optimize(graph)
    assert result.converged and result.iterations < 20
    assert result.cost_after < 0.1 * result.cost_before
    if truth_file is None:
        return
    truth = read_ground_truth(posegraphs / truth_file, graph)
    d = graph.dim
    before = ate_rmse(result.initial[:, :d, d], truth)
    after = ate_rmse(result.poses[:, :d, d], truth)
    assert after < 0.1 * before, (name, before, after)


def test_city10000_ground_truth_formats_agree(posegraphs: Path) -> None:
    # the x-y-theta file and iSAM's noise-free graph (composed odometry) are the same poses,
    # up to the 6-digit rounding of the graph's measurements over 10000 steps
    graph = read_graph(posegraphs / "se-sync/city10000.g2o").parsed.graph
    from_lines = read_ground_truth(posegraphs / "gtsam/ISAM2_GT_city10000.txt", graph)
    from_graph = read_ground_truth(posegraphs / "isam/groundtruth/city10000_groundtruth.txt", graph)
    assert np.abs(from_lines - from_graph).max() < 1e-2


def test_reader_matches_gtsam_read_g2o(posegraphs: Path) -> None:
    for file, is3d in (("se-sync/sphere2500.g2o", True), ("slambook/M3500.g2o", False)):
        graph = read_graph(posegraphs / file).parsed.graph
        factors, values = gtsam.readG2o(str(posegraphs / file), is3d)
        assert factors.size() == graph.n_edges
        for k in (0, 1234, graph.n_edges - 1):
            factor = factors.at(k)
            assert list(factor.keys()) == [graph.sources[k], graph.targets[k]]
            np.testing.assert_allclose(factor.measured().matrix(), graph.measurements[k], atol=1e-9)
            information = graph.information[k]
            if is3d:  # GTSAM orders the Pose3 tangent rotation first
                order = [3, 4, 5, 0, 1, 2]
                information = information[np.ix_(order, order)]
            np.testing.assert_allclose(factor.noiseModel().information(), information, rtol=1e-9, atol=1e-9)
        pose = values.atPose3(7).matrix() if is3d else values.atPose2(7).matrix()
        np.testing.assert_allclose(pose, graph.poses[7], atol=1e-9)


def test_isam_and_g2o_versions_of_sphere2500_agree(posegraphs: Path) -> None:
    # same measurements; iSAM stores square-root information (10 -> 100), se-sync's g2o
    # copy took those numbers as information and rescaled the rotation block for quaternions
    isam = read_graph(posegraphs / "isam/sphere2500.txt").parsed.graph
    g2o = read_graph(posegraphs / "se-sync/sphere2500.g2o").parsed.graph
    order_isam = np.lexsort((isam.targets, isam.sources))
    order_g2o = np.lexsort((g2o.targets, g2o.sources))
    assert np.array_equal(isam.sources[order_isam], g2o.sources[order_g2o])
    assert np.array_equal(isam.targets[order_isam], g2o.targets[order_g2o])
    np.testing.assert_allclose(isam.measurements[order_isam], g2o.measurements[order_g2o], atol=2e-5)
    np.testing.assert_allclose(np.diag(isam.information[0]), [100, 100, 100, 1e4, 1e4, 625])
    assert np.diag(g2o.information[0])[0] == pytest.approx(10.0)


def test_isam2_agrees_with_batch_on_a_small_graph(posegraphs: Path) -> None:
    graph = subgraph(read_graph(posegraphs / "se-sync/intel.g2o").parsed.graph, np.arange(400))
    batch = optimize(graph)
    incremental = optimize(
        graph, SolverOptions(mode="isam2", isam2_relinearize_threshold=0.01, isam2_relinearize_skip=1)
    )
    assert incremental.mode == "isam2" and incremental.iterations >= graph.n_vertices
    assert np.abs(incremental.poses[:, :2, 2] - batch.poses[:, :2, 2]).max() < 0.01
    assert incremental.cost_after == pytest.approx(batch.cost_after, rel=1e-3)


def test_a_robust_kernel_survives_20_percent_false_closures_on_m3500(posegraphs: Path) -> None:
    """The acceptance line of the outlier study: within 10 % of the clean ATE at 20 %."""
    graph_file, truth_file = GRAPHS["M3500"]
    graph = read_graph(posegraphs / graph_file).parsed.graph
    truth = read_ground_truth(posegraphs / truth_file, graph)
    clean = ate_rmse(optimize(graph).poses[:, :2, 2], truth)
    corrupted, false = random_false_closures(graph, 0.2, np.random.default_rng([0, 2]))
    assert false.sum() == 488
    robust = ate_rmse(optimize(corrupted, SolverOptions(kernel="dcs")).poses[:, :2, 2], truth)
    assert robust <= 1.1 * clean, (clean, robust)  # (least squares gives about 40x clean: see the README)


def test_a_graph_lm_cannot_improve_is_reported_as_not_converged(posegraphs: Path) -> None:
    # slambook's INTEL.g2o has an edge whose information has a condition number of 2e11:
    # GTSAM's LM (ours, and readG2o + LM alike) gives up at the largest damping
    graph = read_graph(posegraphs / "slambook/INTEL.g2o").parsed.graph
    result = optimize(graph)
    assert not result.converged and result.cost_after == pytest.approx(result.cost_before)


def test_isam2_falls_back_to_qr_where_cholesky_breaks_down(posegraphs: Path) -> None:
    # se-sync's CSAIL.g2o: iSAM2's Cholesky finds the system indeterminate part-way; QR solves it
    graph = read_graph(posegraphs / "se-sync/CSAIL.g2o").parsed.graph
    with pytest.raises(DataError, match="CSAIL.g2o: GTSAM could not solve the graph: Indeterminate linear system"):
        optimize(graph, SolverOptions(mode="isam2", isam2_factorization="cholesky"))
    incremental = optimize(graph, SolverOptions(mode="isam2"))
    batch = optimize(graph)
    assert incremental.factorization == "qr" and incremental.summary()["isam2_factorization"] == "qr"
    assert np.abs(incremental.poses[:, :2, 2] - batch.poses[:, :2, 2]).max() < 0.01
    assert incremental.cost_after == pytest.approx(batch.cost_after, rel=1e-2)


@pytest.mark.parametrize("file", ["slambook/M3500.g2o", "se-sync/sphere2500.g2o", "se-sync/intel.g2o", "se-sync/smallGrid3D.g2o"])
def test_gtsam_reading_a_plain_g2o_file_gives_the_python_built_problem(file: str, posegraphs: Path) -> None:
    from slamfront.posegraph.solver import prepare, read_problem

    path = posegraphs / file
    loaded = read_graph(path).parsed
    assert loaded.plain_g2o
    graph = loaded.graph
    assert read_problem(path, graph, prepare(graph)[0]) is not None  # the fast path is taken ...
    fast, python = optimize(graph, SolverOptions(), path), optimize(graph, SolverOptions())
    # ... and solves the same problem: the same factors, so the same costs (to rounding: a
    # Pose2 made from our matrix and GTSAM's from the file's angle differ in the last bit,
    # which moves a planar solution by ~1e-6 m within LM's tolerance, the cost by ~1e-11)
    assert fast.cost_before == pytest.approx(python.cost_before, rel=1e-9)
    assert fast.cost_after == pytest.approx(python.cost_after, rel=1e-9, abs=1e-9)
    assert fast.iterations == python.iterations and fast.converged == python.converged
    np.testing.assert_allclose(fast.poses, python.poses, atol=1e-4)
