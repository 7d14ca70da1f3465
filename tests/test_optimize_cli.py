"""``slamfront optimize`` and ``slamfront outliers``: outputs, options, and every user error."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slamfront import DataError
from slamfront.core import geometry
from slamfront.core.alignment import ate_rmse
from slamfront.core.graph_files import format_g2o, parse_graph
from slamfront.core.posegraph import random_false_closures
from slamfront.formats.poses import Trajectory as PoseFile
from slamfront.formats.poses import read_tum, write_tum
from slamfront.posegraph.io import read_trajectory
from slamfront.posegraph.solver import SolverOptions, optimize
from tests.posegraph_fixtures import ring_g2o, ring_graph, ring_truth
from tests.test_cli import _one_line_error


@pytest.fixture
def ring_file(tmp_path: Path) -> Path:
    path = tmp_path / "ring.g2o"
    path.write_text(ring_g2o())
    return path


def test_optimize_writes_every_output(cli, ring_file: Path, tmp_path: Path) -> None:
    truth_file = tmp_path / "truth.tum"
    write_tum(truth_file, PoseFile(np.arange(120.0), geometry.planar_to_spatial(ring_truth())))
    out = tmp_path / "out"
    code, stdout, _ = cli("optimize", ring_file, "-o", out, "--ground-truth", truth_file)
    assert code == 0 and "ATE:" in stdout
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("cost_before", "cost_after", "iterations", "seconds", "ate_rmse_before_m", "ate_rmse_after_m"):
        assert key in metrics
    assert metrics["converged"] and metrics["cost_after"] < metrics["cost_before"]
    assert metrics["ate_rmse_after_m"] < 0.5 * metrics["ate_rmse_before_m"]
    assert metrics["n_vertices"] == 120 and metrics["n_loop_closures"] == 60
    optimised = parse_graph((out / "optimized.g2o").read_text().splitlines(), "optimized.g2o").graph
    trajectory = read_tum(out / "trajectory.tum")
    np.testing.assert_allclose(geometry.planar_to_spatial(optimised.poses), trajectory.poses, atol=1e-9)
    assert ate_rmse(trajectory.positions[:, :2], ring_truth()[:, :2, 2]) == pytest.approx(metrics["ate_rmse_after_m"], rel=1e-6)
    assert (out / "before_after.svg").stat().st_size > 0 and "(before_after.svg)" in (out / "report.md").read_text()


def test_ground_truth_as_xytheta_lines_or_a_noise_free_graph(cli, ring_file: Path, tmp_path: Path) -> None:
    params = geometry.se2_parameters(ring_truth())
    lines = tmp_path / "gt.txt"
    lines.write_text("\n".join(" ".join(f"{v:.12g}" for v in row) for row in params) + "\n")
    noise_free = tmp_path / "gt.g2o"
    noise_free.write_text(_noise_free_ring())
    ates = []
    for truth in (lines, noise_free):
        out = tmp_path / truth.suffix[1:]
        code, _, err = cli("optimize", ring_file, "-o", out, "--ground-truth", truth, "--no-plots")
        assert code == 0, err
        ates.append(json.loads((out / "metrics.json").read_text())["ate_rmse_after_m"])
    assert ates[0] == pytest.approx(ates[1], rel=1e-6)


def _noise_free_ring() -> str:
    graph = ring_graph()
    exact = geometry.relative(ring_truth()[graph.sources], ring_truth()[graph.targets])
    return format_g2o(replace(graph, measurements=exact))


def test_isam_format_and_isam2_mode(cli, tmp_path: Path) -> None:
    graph = ring_graph()
    rows = []
    for s, t, m, info in zip(graph.sources, graph.targets, graph.measurements, graph.information):
        root = np.linalg.cholesky(info).T  # upper-triangular square root, as iSAM stores
        numbers = [*geometry.se2_parameters(m), *root[np.triu_indices(3)]]
        rows.append(f"EDGE2 {s} {t} " + " ".join(repr(float(v)) for v in numbers))
    path = tmp_path / "ring.txt"
    path.write_text("\n".join(rows) + "\n")
    code, stdout, err = cli("optimize", path, "-o", tmp_path / "o", "--mode", "isam2", "--no-plots")
    assert code == 0, err
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["format"] == "isam" and metrics["mode"] == "isam2"
    batch = optimize(graph)
    assert metrics["cost_after"] == pytest.approx(batch.cost_after, rel=1e-2)


def test_gnc_rejects_the_false_closures_and_keeps_the_true_ones() -> None:
    graph = ring_graph()
    corrupted, false = random_false_closures(graph, 0.1, np.random.default_rng(1))
    clean = optimize(graph)
    result = optimize(corrupted, SolverOptions(kernel="gnc", gnc_warm_start="none"))
    assert result.weights is not None
    assert np.all(result.weights[false] < 0.5)
    assert np.all(result.weights[corrupted.is_odometry()] == 1.0)  # known inliers
    # the TLS threshold (99 % chi-square quantile) may drop a rare true closure by design
    assert np.sum(result.weights[~false] < 0.5) <= 2
    truth = ring_truth()[:, :2, 2]
    clean_ate = ate_rmse(clean.poses[:, :2, 2], truth)
    assert ate_rmse(result.poses[:, :2, 2], truth) < 1.1 * clean_ate
    assert ate_rmse(optimize(corrupted).poses[:, :2, 2], truth) > 3 * clean_ate


def test_outliers_command_writes_table_and_plot(cli, ring_file: Path, tmp_path: Path) -> None:
    truth_file = tmp_path / "truth.tum"
    write_tum(truth_file, PoseFile(np.arange(120.0), geometry.planar_to_spatial(ring_truth())))
    out = tmp_path / "study"
    code, stdout, err = cli(
        "outliers", ring_file, "--ground-truth", truth_file, "--rates", "0.2", "--methods", "none", "dcs", "gnc",
        "-o", out, "-q",
    )
    assert code == 0, err
    rows = json.loads((out / "outliers.json").read_text())
    assert [(r["rate"], r["method"]) for r in rows] == [(0.0, "none"), (0.0, "dcs"), (0.0, "gnc"), (0.2, "none"),
                                                         (0.2, "dcs"), (0.2, "gnc")]
    assert rows[3]["n_false"] == 15  # 15 / (15 + 60) = 20 %
    assert "| ring.g2o | 20% (15) | dcs |" in (out / "outliers.md").read_text()
    assert (out / "outliers.png").stat().st_size > 0


BAD_GRAPHS = {
    "malformed": ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0\n", "bad.g2o:2: EDGE_SE2 needs 11 values"),
    "unknown vertex": (
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 7 1 0 0 1 0 0 1 0 1\n",
        "bad.g2o:4: edge 1 -> 7 refers to vertex 7, which no VERTEX record declares",
    ),
    "disconnected": (
        "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 3 4 1 0 0 1 0 0 1 0 1\n",
        "bad.g2o: the graph is disconnected: 2 pieces; 2 vertices (e.g. 3, 4) have no chain of edges to vertex 0",
    ),
    "not positive definite": (
        "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 0 0 1\n",
        "bad.g2o:2: information matrix of edge 1 -> 2 is not positive definite",
    ),
    "unknown record": ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_FOO 1 2\n", "bad.g2o:2: unknown record 'EDGE_FOO'"),
    "empty": ("", "bad.g2o: no edges found"),
    "negative id": ("EDGE_SE2 -1 0 1 0 0 1 0 0 1 0 1\n", "bad.g2o: vertex ids must be non-negative, got -1"),
}


@pytest.mark.parametrize("case", list(BAD_GRAPHS))
def test_bad_graphs_fail_in_one_line(cli, tmp_path: Path, case: str) -> None:
    text, expected = BAD_GRAPHS[case]
    path = tmp_path / "bad.g2o"
    path.write_text(text)
    out = tmp_path / "out"
    line = _one_line_error(*cli("optimize", path, "-o", out)[::2])
    assert expected in line
    assert not out.exists()  # nothing half-written


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--kernel", "gnc", "--mode", "isam2"], "kernel gnc needs mode batch"),
        (["--kernel", "cauchy", "--kernel-parameter", "-1"], "--kernel-parameter: Input should be greater than 0"),
        (["--max-iterations", "0"], "--max-iterations"),
    ],
)
def test_bad_options_fail_in_one_line(cli, ring_file: Path, args: list[str], expected: str) -> None:
    assert expected in _one_line_error(*cli("optimize", ring_file, *args)[::2])


def test_bad_inputs_fail_in_one_line(cli, ring_file: Path, tmp_path: Path) -> None:
    assert "nope.g2o: no such file" in _one_line_error(*cli("optimize", tmp_path / "nope.g2o")[::2])
    short = tmp_path / "short.txt"
    short.write_text("0 0 0\n1 0 0\n")
    line = _one_line_error(*cli("optimize", ring_file, "--ground-truth", short)[::2])
    assert "short.txt: 2 rows (vertex 0 to 1) do not cover vertex 119" in line
    tum = tmp_path / "few.tum"
    tum.write_text("0.5 0 0 0 0 0 0 1\n")
    assert "cannot tell which pose is which vertex" in _one_line_error(*cli("optimize", ring_file, "--ground-truth", tum)[::2])
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("hello")
    assert "not an MCAP file" in _one_line_error(*cli("optimize", not_mcap)[::2])
    line = _one_line_error(*cli("outliers", ring_file, "--ground-truth", tum, "--ground-truth", tum)[::2])
    assert "--ground-truth: 2 files for 1 graphs" in line
    assert "--rates: 1.0 is not in [0, 1)" in _one_line_error(*cli("outliers", ring_file, "--rates", "1")[::2])


def test_trajectory_files_by_column_count(tmp_path: Path) -> None:
    files = {
        "gt.tum": "# t x y z qx qy qz qw\n1.5 1 2 3 0 0 0 1\n2.5 1 2 4 0 0 1 0\n",
        "xy.txt": "0 0 0\n1 0 1.5707963267948966\n",
        "k.txt": "1 0 0 5 0 1 0 6 0 0 1 7\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    tum, kind = read_trajectory(tmp_path / "gt.tum")
    assert kind == "tum" and tum.timestamps.tolist() == [1.5, 2.5]
    np.testing.assert_allclose(tum.poses[1, :3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    planar, kind = read_trajectory(tmp_path / "xy.txt")
    assert kind == "xytheta" and planar.positions[1].tolist() == [1.0, 0.0, 0.0]
    np.testing.assert_allclose(planar.poses[1, :2, :2], [[0, -1], [1, 0]], atol=1e-12)
    kitti, kind = read_trajectory(tmp_path / "k.txt")
    assert kind == "kitti" and kitti.positions[0].tolist() == [5.0, 6.0, 7.0]
    for text, message in [
        ("1 2 3 4 5\n", "t.txt:1: 5 columns"),
        ("1 2 3\n1 2\n", "t.txt:2: expected 3 numbers (x y theta), got 2"),
        ("1 2 x\n", "t.txt:1: not a number"),
        ("# nothing\n", "t.txt: no poses in the file"),
    ]:
        (tmp_path / "t.txt").write_text(text)
        with pytest.raises(DataError, match=re.escape(message)):
            read_trajectory(tmp_path / "t.txt")


def test_a_failed_plot_fails_the_command_and_keeps_the_results(cli, ring_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert cli("optimize", ring_file, "-o", out)[0] == 0
    (out / "before_after.svg.tmp").mkdir()  # the plot's temporary file cannot be written
    code, stdout, err = cli("optimize", ring_file, "-o", out)
    assert code == 1 and "cost:" in stdout  # the results are shown ...
    assert "before_after.svg: the plot failed" in err.strip().splitlines()[-1]  # ... and the failure said last
    assert not (out / "before_after.svg").exists()  # no plot of the previous run beside these results
    assert "The plot failed" in (out / "report.md").read_text()
    assert "the plot failed" in json.loads((out / "metrics.json").read_text())["plot_failed"]
    assert (out / "optimized.g2o").stat().st_size > 0 and (out / "trajectory.tum").stat().st_size > 0


def test_no_plots_in_a_reused_folder_leaves_no_older_plot(cli, ring_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert cli("optimize", ring_file, "-o", out)[0] == 0 and (out / "before_after.svg").exists()
    code, _, err = cli("optimize", ring_file, "-o", out, "--no-plots", "--kernel", "cauchy")
    assert code == 0, err
    assert not (out / "before_after.svg").exists()  # it would show the first run's solve beside the second's numbers
    assert "before_after.svg" not in (out / "report.md").read_text()


def test_optimize_imports_no_library_it_does_not_use(ring_file: Path, tmp_path: Path) -> None:
    # the plot is SVG text: Pillow, pydantic, matplotlib and the vision libraries stay out of the process
    import subprocess
    import sys

    heavy = ("matplotlib", "PIL", "pydantic", "cv2", "open3d", "scipy", "numba", "mcap")
    code = (
        "import sys; from slamfront.cli import main; "
        f"assert main(['optimize', {str(ring_file)!r}, '-o', {str(tmp_path / 'o')!r}]) == 0; "
        f"print('loaded:', ','.join(m for m in {heavy!r} if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip().splitlines()[-1] == "loaded:"


@pytest.mark.parametrize(
    "options",
    [{"kernel_parameter": -1}, {"max_iterations": 0}, {"mode": "online"}, {"gnc_probability": 1.0},
     {"absolute_tolerance": -1e-3}, {"kernel": "gnc", "mode": "isam2"}],
)
def test_solver_options_say_what_pydantic_says_in_a_back_end_config(options: dict[str, object]) -> None:
    from pydantic import ValidationError

    from slamfront_plugins.backends.gtsam_pose_graph import GtsamPoseGraph

    with pytest.raises(ValueError) as direct:
        SolverOptions(**options)
    with pytest.raises(ValidationError) as in_config:
        GtsamPoseGraph.Config(solver=options)
    assert str(direct.value).split(": ", 1)[-1] in in_config.value.errors()[0]["msg"]
    assert GtsamPoseGraph.Config(solver={"max_iterations": "7"}).solver == SolverOptions(max_iterations=7)


def _ring_with_vertices(path: Path) -> Path:
    from slamfront.core.posegraph import compose_initial_poses

    graph = ring_graph()
    path.write_text(format_g2o(graph, compose_initial_poses(graph)))  # vertex lines, then edges
    return path


def test_a_file_changed_after_reading_is_not_read_again_by_gtsam(tmp_path: Path) -> None:
    from slamfront.posegraph.io import read_graph
    from slamfront.posegraph.solver import prepare, read_problem

    path = _ring_with_vertices(tmp_path / "ring.g2o")
    parsed = read_graph(path).parsed
    assert parsed.plain_g2o
    initial = prepare(parsed.graph)[0]
    assert read_problem(path, parsed.graph, initial) is not None
    expected = optimize(parsed.graph)
    lines = path.read_text().splitlines()
    for changed in (
        [*lines[:3], "VERTEX_SE2 3 100 100 0", *lines[4:]],  # a vertex moved
        [*lines[:-1], lines[-1].rsplit(" ", 1)[0] + " 7"],  # an information entry
        [*lines, "EDGE_SE2 0 5 1 0 0 1 0 0 1 0 1"],  # one more edge
        ["VERTEX_SE2 0 0 0 0"],  # not the graph at all
    ):
        path.write_text("\n".join(changed) + "\n")
        assert read_problem(path, parsed.graph, initial) is None
        result = optimize(parsed.graph, SolverOptions(), path)  # the graph as read, built in Python
        assert result.cost_after == pytest.approx(expected.cost_after, rel=1e-9, abs=1e-12)
    path.unlink()  # gone (GTSAM raises) or a folder (GTSAM reads nothing)
    assert read_problem(path, parsed.graph, initial) is None
    path.mkdir()
    assert read_problem(path, parsed.graph, initial) is None
