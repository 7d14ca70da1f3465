"""The synthetic world: deterministic, geometrically consistent, with correct ground truth."""

from __future__ import annotations

import numpy as np

from slamfront_plugins.sources.synthetic import SyntheticWorld
from slamfront_plugins.sources.synthetic_world import Lighting, Route, StreetWorld

SMALL = dict(frames_per_traversal=30, route_length_m=90, image_width=64, image_height=48)


def test_same_seed_same_bits_other_seed_other_world() -> None:
    a = list(SyntheticWorld(SyntheticWorld.Config(**SMALL)).frames())
    b = list(SyntheticWorld(SyntheticWorld.Config(**SMALL)).frames())
    c = list(SyntheticWorld(SyntheticWorld.Config(seed=1, **SMALL)).frames())
    assert all(x.image.tobytes() == y.image.tobytes() for x, y in zip(a, b))
    assert all(x.depth.tobytes() == y.depth.tobytes() for x, y in zip(a, b))
    assert np.mean([np.abs(x.image.astype(int) - y.image.astype(int)).mean() for x, y in zip(a, c)]) > 10


def test_paired_layout_and_ground_truth() -> None:
    source = SyntheticWorld(SyntheticWorld.Config(**SMALL))
    frames = list(source.frames())
    assert len(frames) == len(source) == 60
    assert [f.traversal for f in frames] == ["reference"] * 30 + ["query"] * 30
    assert np.all(np.diff([f.timestamp for f in frames]) > 0)
    truth = source.loop_ground_truth()
    assert truth.queries.tolist() == list(range(30, 60))
    assert truth.is_correct(np.array([35, 35, 35]), np.array([5, 8, 9])).tolist() == [True, True, False]
    # query i is at the place of reference i, a little to the side
    for k in (0, 12, 29):
        gap = np.linalg.norm(frames[k].pose[:3, 3] - frames[30 + k].pose[:3, 3])
        assert 0.1 < gap < 0.6


def test_stream_ground_truth_links_laps() -> None:
    source = SyntheticWorld(SyntheticWorld.Config(mode="stream", laps=3, **SMALL))
    truth = source.loop_ground_truth()
    assert len(truth) == 90
    has = truth.has_true_match()
    assert not has[:29].any() and has[29:].all()

    def matches(frame: int) -> list[int]:
        row = truth.rows_of(np.array([frame]))[0]
        return truth.matches[truth.indptr[row] : truth.indptr[row + 1]].tolist()

    # frame 65 (lap 2, position 5) revisits positions 5 +- 1 of laps 0 and 1 (3 m reach, 3 m steps)
    assert matches(65) == [4, 5, 6, 34, 35, 36]
    # the route is closed: the last frame of a lap is back at the start of that lap too
    assert matches(29) == [0] and matches(59) == [0, 28, 29, 30]


def test_depth_back_projects_onto_the_geometry() -> None:
    source = SyntheticWorld(SyntheticWorld.Config(**SMALL, noise_std=0))
    frame = next(iter(source.frames()))
    k = frame.camera.matrix
    v, u = np.nonzero(frame.depth > 0)
    z = frame.depth[v, u].astype(np.float64)
    cam = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], axis=1)
    world = cam @ frame.pose[:3, :3].T + frame.pose[:3, 3]
    # every return is on the ground (z = 0) or on a facade (vertical, up to 22 m tall)
    on_ground = np.abs(world[:, 2]) < 1e-3
    assert on_ground.mean() > 0.2
    assert np.all((world[:, 2] > -1e-3) & (world[:, 2] < 22.01))
    # the pose convention: camera z (forward) is horizontal, y points down
    assert abs(frame.pose[2, 2]) < 1e-9 and frame.pose[2, 1] < -0.99


def test_route_is_closed_and_has_requested_length() -> None:
    route = Route(100.0, 60.0, 10.0)
    start, _ = route.at(np.array([0.0]))
    end, _ = route.at(np.array([route.length - 1e-9]))
    assert np.allclose(start, end, atol=1e-6)
    s = np.linspace(0, route.length, 2001)
    pos, head = route.at(s)
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert np.allclose(steps, s[1] - s[0], rtol=1e-3)  # unit speed everywhere, corners included
    assert np.allclose(np.linalg.norm(head, axis=1), 1.0)


def test_own_patterns_give_each_world_its_own_road_and_facade_texture() -> None:
    """By default two worlds share the road and the n-th building's bricks and letters at a
    place (what made another world's frames match as the same place); ``own_patterns`` seeds them."""
    points = np.stack([np.linspace(-20, 20, 500), np.linspace(-5, 5, 500), np.zeros(500)], axis=1)
    day = Lighting.of("day")
    shared = [StreetWorld(seed, 90.0) for seed in (0, 1)]
    own = [StreetWorld(seed, 90.0, own_patterns=True) for seed in (0, 1)]
    assert np.array_equal(shared[0]._ground_colour(points, day), shared[1]._ground_colour(points, day))
    assert not np.allclose(own[0]._ground_colour(points, day), own[1]._ground_colour(points, day))
    cells = (np.arange(50), np.arange(50) * 3)
    assert np.array_equal(shared[0]._pattern(*cells), shared[1]._pattern(*cells))
    assert np.mean(own[0]._pattern(*cells) == own[1]._pattern(*cells)) < 0.1
    # a world's own patterns are the same in every rendering of it
    assert np.array_equal(own[0]._pattern(*cells), StreetWorld(0, 90.0, own_patterns=True)._pattern(*cells))
