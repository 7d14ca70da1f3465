"""Pose-graph arrays, rigid-transform helpers and the text formats, without files."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core import geometry
from slamfront.core.errors import CoreError
from slamfront.core.graph_files import format_g2o, parse_graph
from slamfront.core.posegraph import (
    check_connected,
    compose_initial_poses,
    random_false_closures,
    spanning_tree,
    subgraph,
)

SQUARE_2D = """\
# a unit square driven once, closed by one loop closure (no VERTEX lines)
EDGE_SE2 0 1 1 0 1.5707963267948966 100 0 0 100 0 400
EDGE_SE2 1 2 1 0 1.5707963267948966 100 0 0 100 0 400
EDGE_SE2 2 3 1 0 1.5707963267948966 100 0 0 100 0 400
EDGE_SE2 3 0 1 0 1.5707963267948966 100 0 0 100 0 400
"""


def _edge3(i: int, j: int, t: tuple[float, float, float], q: tuple[float, float, float, float]) -> str:
    info = []
    for row in range(6):
        info += [100.0 if col == row else 0.0 for col in range(row, 6)]
    return f"EDGE_SE3:QUAT {i} {j} {' '.join(map(str, t))} {' '.join(map(str, q))} {' '.join(map(str, info))}"


def test_lie_helpers_round_trip() -> None:
    rng = np.random.default_rng(0)
    quaternions = Rotation.random(20, random_state=1).as_quat()
    transforms = geometry.poses_from_quaternions(rng.normal(size=(20, 3)), quaternions)
    np.testing.assert_allclose(geometry.invert(transforms) @ transforms, np.broadcast_to(np.eye(4), (20, 4, 4)), atol=1e-12)
    translation, back = transforms[:, :3, 3], geometry.quaternions_of(transforms)
    assert np.all(back[:, 3] >= 0)
    np.testing.assert_allclose(geometry.poses_from_quaternions(translation, back), transforms, atol=1e-12)
    planar = geometry.se2(rng.normal(size=5), rng.normal(size=5), rng.uniform(-3, 3, 5))
    np.testing.assert_allclose(geometry.se2(*geometry.se2_parameters(planar).T), planar, atol=1e-12)
    spatial = geometry.planar_to_spatial(planar)
    assert np.allclose(spatial[:, 2, 3], 0) and np.allclose(spatial[:, :2, 3], planar[:, :2, 2])
    # iSAM's roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)
    euler = geometry.se3_from_euler(np.zeros(3), np.array([0.1, -0.2, 0.3]))[0, :3, :3]
    expected = Rotation.from_euler("z", 0.3).as_matrix() @ Rotation.from_euler("y", -0.2).as_matrix()
    np.testing.assert_allclose(euler, expected @ Rotation.from_euler("x", 0.1).as_matrix(), atol=1e-12)
    assert geometry.rotation_angle_deg(geometry.exp_se3(np.array([0, 0, 0, 0, 0.4, 0]))) == pytest.approx(np.rad2deg(0.4))


def test_g2o_2d_without_vertices_composes_odometry() -> None:
    parsed = parse_graph(SQUARE_2D.splitlines(), "square.g2o")
    graph = parsed.graph
    assert parsed.format == "g2o" and graph.dim == 2 and graph.poses is None
    assert graph.ids.tolist() == [0, 1, 2, 3] and graph.n_edges == 4
    assert graph.is_odometry().tolist() == [True, True, True, False]
    np.testing.assert_allclose(graph.information[0], np.diag([100.0, 100.0, 400.0]))
    assert graph.where(3) == "square.g2o:5"
    poses = compose_initial_poses(graph)
    np.testing.assert_allclose(poses[:, :2, 2], [[0, 0], [1, 0], [1, 1], [0, 1]], atol=1e-12)


def test_g2o_3d_with_vertices_and_fix() -> None:
    text = [
        "VERTEX_SE3:QUAT 5 0 0 0 0 0 0 1",
        "VERTEX_SE3:QUAT 6 1 0 0 0 0 0.7071067811865476 0.7071067811865476",
        _edge3(5, 6, (1, 0, 0), (0, 0, 0.7071067811865476, 0.7071067811865476)),
        "FIX 5",
    ]
    graph = parse_graph(text, "two.g2o").graph
    assert graph.dim == 3 and graph.ids.tolist() == [5, 6] and graph.fixed.tolist() == [5]
    np.testing.assert_allclose(graph.poses[1], graph.measurements[0], atol=1e-12)


def test_isam_square_root_information_is_squared() -> None:
    # sqrt-information upper triangle sxx sxy sxt syy syt stt: information = R^T R
    graph = parse_graph(["EDGE2 0 1 1 0 0 10 1 0 20 0 5"], "isam.txt").graph
    root = np.array([[10.0, 1.0, 0.0], [0.0, 20.0, 0.0], [0.0, 0.0, 5.0]])
    np.testing.assert_allclose(graph.information[0], root.T @ root)
    graph3 = parse_graph(["EDGE3 0 1 1 2 3 0.1 0.2 0.3 " + " ".join(["10"] + ["0"] * 5 + ["10"] + ["0"] * 4 + ["10"] + ["0"] * 3 + ["2", "0", "0", "2", "0", "2"])], "i3").graph
    np.testing.assert_allclose(np.diag(graph3.information[0]), [100, 100, 100, 4, 4, 4])
    np.testing.assert_allclose(graph3.measurements[0, :3, :3], geometry.se3_from_euler(np.zeros(3), np.array([0.1, 0.2, 0.3]))[0, :3, :3])


def test_landmark_records_are_counted_and_skipped() -> None:
    parsed = parse_graph(["ODOMETRY 0 1 1 0 0 1 0 0 1 0 1", "LANDMARK 1 7 2 3 1 0 1"], "v.txt")
    assert parsed.format == "isam" and parsed.skipped == {"LANDMARK": 1}


def test_g2o_round_trip() -> None:
    rng = np.random.default_rng(3)
    lines = ["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1"]
    for k in range(1, 6):
        lines.append(f"VERTEX_SE3:QUAT {k} {k} 0 0 0 0 0 1")
    for k in range(5):
        lines.append(_edge3(k, k + 1, tuple(rng.normal(size=3)), tuple(Rotation.random(random_state=k).as_quat())))
    lines.append(_edge3(0, 5, (5, 0, 0), (0, 0, 0, 1)))
    graph = parse_graph(lines, "g").graph
    again = parse_graph(format_g2o(graph).splitlines(), "again").graph
    np.testing.assert_allclose(again.measurements, graph.measurements, atol=1e-10)
    np.testing.assert_allclose(again.information, graph.information, atol=1e-9)
    np.testing.assert_allclose(again.poses, graph.poses, atol=1e-10)
    planar = parse_graph(SQUARE_2D.splitlines(), "square").graph
    written = parse_graph(format_g2o(planar, compose_initial_poses(planar)).splitlines(), "w").graph
    np.testing.assert_allclose(written.poses, compose_initial_poses(planar), atol=1e-10)


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (["EDGE_SE2 0 1 1 0 0 1 0 0 1 0"], "bad.g2o:1: EDGE_SE2 needs 11 values (2 ids + 9 numbers), got 10"),
        (["EDGE_SE2 0 1 1 0 zero 1 0 0 1 0 1"], "bad.g2o:1: EDGE_SE2: 'zero' is not a number"),
        (["EDGE_SE2 0 1.5 1 0 0 1 0 0 1 0 1"], "bad.g2o:1: EDGE_SE2: vertex ids must be integers"),
        (["", "FOO 1 2"], "bad.g2o:2: unknown record 'FOO'"),
        (["VERTEX2 0 0 0 0"], "TORO"),
        (["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0", "EDGE_SE2 0 2 1 0 0 1 0 0 1 0 1"],
         "bad.g2o:3: edge 0 -> 2 refers to vertex 2, which no VERTEX record declares"),
        (["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 0 1 0 0", "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1"], "vertex 0 is declared twice"),
        (["EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -1"], "bad.g2o:1: information matrix of edge 0 -> 1 is not positive definite"),
        (["EDGE_SE2 0 1 1 0 0 1 2 0 1 0 1"], "not positive definite"),
        (["EDGE_SE2 0 0 1 0 0 1 0 0 1 0 1"], "bad.g2o:1: edge connects vertex 0 to itself"),
        (["EDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1"], "bad.g2o:1: EDGE_SE2 has a non-finite number"),
        (["EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", "EDGE2 1 2 1 0 0 1 0 0 1 0 1"], "mixes g2o (EDGE_SE2, line 1) and iSAM"),
        (["EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", _edge3(1, 2, (0, 0, 0), (0, 0, 0, 1))], "mixes 2-D"),
        (["# nothing"], "no edges found"),
        ([_edge3(0, 1, (0, 0, 0), (0, 0, 0, 0))], "bad.g2o:1: quaternion has zero length"),
    ],
)
def test_bad_graph_text_names_file_and_line(lines: list[str], message: str) -> None:
    with pytest.raises(CoreError) as error:
        parse_graph(lines, "bad.g2o")
    assert message in str(error.value)


def test_format_given_must_match() -> None:
    with pytest.raises(CoreError, match="is a g2o record, but the format was given as isam"):
        parse_graph(SQUARE_2D.splitlines(), "s", "isam")


def test_disconnected_graph_is_refused() -> None:
    graph = parse_graph(["EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", "EDGE_SE2 5 6 1 0 0 1 0 0 1 0 1"], "two.g2o").graph
    with pytest.raises(CoreError, match=r"two.g2o: the graph is disconnected: 2 pieces; 2 vertices \(e.g. 5, 6\)"):
        check_connected(graph)
    with pytest.raises(CoreError, match="disconnected"):
        compose_initial_poses(graph)


def test_spanning_tree_prefers_odometry() -> None:
    # chain 0-1-2-3 plus a loop 0-3: vertex 3 must be reached through odometry, not the loop
    graph = parse_graph(SQUARE_2D.splitlines(), "s").graph
    order, parent = spanning_tree(graph)
    assert order.tolist() == [0, 1, 2, 3]
    assert parent.tolist() == [-1, 0, 1, 2]


def test_subgraph_keeps_edges_inside() -> None:
    graph = parse_graph(SQUARE_2D.splitlines(), "s").graph
    part = subgraph(graph, np.array([0, 1, 2]))
    assert part.ids.tolist() == [0, 1, 2] and part.n_edges == 2


def test_false_closures_follow_the_rate() -> None:
    rng = np.random.default_rng(0)
    n = 200
    lines = [f"EDGE_SE2 {k} {k + 1} 1 0 0.01 10 0 0 10 0 10" for k in range(n - 1)]
    lines += [f"EDGE_SE2 {k} {k + 50} 0 0 0 20 0 0 20 0 20" for k in range(0, 100, 5)]  # 20 true loops
    graph = parse_graph(lines, "g").graph
    corrupted, false = random_false_closures(graph, 0.2, rng)
    assert false.sum() == 5 and corrupted.n_edges == graph.n_edges + 5  # 5 / (5 + 20) = 20 %
    added = np.flatnonzero(false)
    assert np.all(np.abs(corrupted.targets[added] - corrupted.sources[added]) >= 10)
    np.testing.assert_allclose(corrupted.information[added], np.broadcast_to(np.diag([20.0] * 3), (5, 3, 3)))
    same, none = random_false_closures(graph, 0.0, rng)
    assert same is graph and not none.any()
    with pytest.raises(CoreError, match=r"\[0, 1\)"):
        random_false_closures(graph, 1.0, rng)


def test_components_label_each_piece_from_the_first_vertex() -> None:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from slamfront.core.posegraph import connected_labels

    # two pieces and a lone vertex, edges listed backwards
    assert connected_labels(6, np.array([4, 1, 2]), np.array([5, 0, 1])).tolist() == [0, 0, 0, 1, 2, 2]
    assert connected_labels(1, np.array([], np.int64), np.array([], np.int64)).tolist() == [0]
    assert connected_labels(4, np.array([3]), np.array([3])).tolist() == [0, 1, 2, 3]  # a self-loop joins nothing
    rng = np.random.default_rng(0)
    for trial in range(100):
        n = int(rng.integers(1, 200))
        a, b = rng.integers(0, n, n), rng.integers(0, n, n)
        if trial % 3 == 0:  # a long chain, listed backwards: the slowest case for label propagation
            a = np.arange(n - 1)[::-1]
            b = a + 1
        _, expected = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
        assert connected_labels(n, a, b).tolist() == expected.tolist()


def test_the_fast_reader_and_the_line_by_line_reader_agree() -> None:
    from slamfront.core import graph_files

    text = [
        "# a comment line", "VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0.1  # trailing comment", "VERTEX_SE2 2 2 0 0.2",
        "EDGE_SE2 0 1 1 0 0.1 10 0 0 10 0 20", "LANDMARK 1 7 2 3 1 0 1", "EDGE_SE2 1 2 1 0 0.1 10 0 0 10 0 20",
        "", "EDGE_SE2 0 2 2.0000000000000004 1e-3 .2 10 1 0 10 0 20", "FIX 0",
    ]
    fast = graph_files._parse_regular(text, "g.g2o", "auto")
    checked = graph_files._parse_checked(text, "g.g2o", "auto")
    assert fast.format == checked.format and fast.skipped == checked.skipped == {"LANDMARK": 1}
    for name in ("ids", "poses", "sources", "targets", "measurements", "information", "fixed", "lines"):
        np.testing.assert_array_equal(getattr(fast.graph, name), getattr(checked.graph, name))
    for irregular in (text + ["EDGE_SE2 0 1 1 0"], text + ["EDGE_SE2 0 1 1 0 x 1 0 0 1 0 1"], text + ["EDGE_FOO 1"],
                      text + ["EDGE_SE2 0 1.5 1 0 0 1 0 0 1 0 1"], text + ["FIX a"]):
        with pytest.raises(graph_files._Irregular):
            graph_files._parse_regular(irregular, "g.g2o", "auto")


def test_spellings_only_python_reads_go_to_the_line_by_line_reader() -> None:
    from slamfront.core import graph_files

    # Python's float and int take "1_0" (and other digits than ASCII); numpy's decimal reader
    # does not: the fast reader hands over, and the numbers are Python's
    for odd in ("1_0", "\u0661"):
        text = ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0", f"EDGE_SE2 0 1 {odd} 0 0 1 0 0 1 0 1"]
        with pytest.raises(graph_files._Irregular):
            graph_files._parse_regular(text, "g.g2o", "auto")
        parsed = parse_graph(text, "g.g2o")
        assert parsed.graph.measurements[0, 0, 2] == float(odd) and not parsed.plain_g2o


@pytest.mark.parametrize(
    ("extra", "plain"),
    [([], True), (["# a comment"], False), (["FIX 0"], False), (["LANDMARK 1 7 2 3 1 0 1"], False),
     (["VERTEX_SE2 1_0 2 0 0", "EDGE_SE2 1 10 1 0 0 1 0 0 1 0 1"], False)],  # Python's int, not numpy's
)
def test_plain_g2o_files_are_told_apart(extra: list[str], plain: bool) -> None:
    # plain: only what GTSAM's readG2o reads the same way (the solver still checks it did)
    text = ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0", "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", *extra]
    assert parse_graph(text, "g.g2o").plain_g2o is plain
    assert not parse_graph(SQUARE_2D.splitlines()[1:], "edges only").plain_g2o  # no vertex lines: composed odometry
