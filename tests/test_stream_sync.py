"""Pairing streams by nearest stamp, loop truth from positions, the /tf tree: pure functions on synthetic data."""

from __future__ import annotations

import numpy as np
import pytest

from slamfront.core.geometry import se3_from_euler
from slamfront.core.loops import revisits_from_positions
from slamfront.core.sync import StreamPairing
from slamfront.formats.ros import TransformTree

MS = 1_000_000


def test_each_image_gets_its_nearest_partner_once_both_sides_are_seen() -> None:
    pairing = StreamPairing(["depth"], tolerance_ns=10 * MS)
    assert pairing.add_primary(100 * MS, 100 * MS, "image 100") == []  # no depth after it yet
    assert pairing.add_partner("depth", 96 * MS, 101 * MS, "depth 96") == []  # a later one may be nearer
    decided = pairing.add_partner("depth", 111 * MS, 112 * MS, "depth 111")  # past 100 + 10 ms: settled
    assert [(p.item, p.partners["depth"][1]) for p in decided] == [("image 100", "depth 96")]
    decided = pairing.add_primary(133 * MS, 134 * MS, "image 133") + pairing.finish()
    assert [(p.item, p.partners["depth"], p.complete) for p in decided] == [("image 133", None, False)]


def test_partners_may_arrive_before_or_after_the_image() -> None:
    pairing = StreamPairing(["depth", "pose"], tolerance_ns=5 * MS)
    decided = []
    decided += pairing.add_partner("pose", 48 * MS, 48 * MS, "pose 48")
    decided += pairing.add_partner("pose", 52 * MS, 52 * MS, "pose 52")  # ties go to the earlier one
    decided += pairing.add_partner("pose", 60 * MS, 60 * MS, "pose 60")
    decided += pairing.add_primary(50 * MS, 61 * MS, "image 50")  # recorded late (driver latency)
    decided += pairing.add_partner("depth", 47 * MS, 62 * MS, "depth 47")
    assert decided == []  # a depth stamped 50-53 ms may still come
    decided += pairing.add_partner("depth", 51 * MS, 63 * MS, "depth 51")  # nearer than anything later can be
    assert len(decided) == 1
    assert decided[0].partners == {"depth": (51 * MS, "depth 51"), "pose": (48 * MS, "pose 48")}


def test_a_partner_with_the_very_stamp_decides_at_once() -> None:
    pairing = StreamPairing(["depth", "pose"], tolerance_ns=20 * MS)
    pairing.add_primary(100 * MS, 100 * MS, "image")
    pairing.add_partner("depth", 100 * MS, 101 * MS, "depth")
    decided = pairing.add_partner("pose", 100 * MS, 102 * MS, "pose")
    assert [p.item for p in decided] == ["image"] and len(pairing) == 0


def test_a_partner_stream_that_stops_does_not_hold_images_forever() -> None:
    pairing = StreamPairing(["depth"], tolerance_ns=10 * MS, patience_ns=1000 * MS)
    pairing.add_partner("depth", 0, 0, "depth 0")
    decided = []
    for k in range(1, 60):  # images at 30 Hz, depth stopped after the first
        decided += pairing.add_primary(33 * k * MS, 33 * k * MS, k)
        assert len(pairing) <= 32  # about a second of images at most
    assert decided and all(p.partners["depth"] is None for p in decided)


def test_memory_holds_only_messages_near_the_present() -> None:
    pairing = StreamPairing(["pose"], tolerance_ns=20 * MS)
    for k in range(10_000):  # images at 10 Hz, poses at 200 Hz
        t = k * 5 * MS
        pairing.add_partner("pose", t, t, k)
        if k % 20 == 0:
            pairing.add_primary(t, t, k)
    assert len(pairing.streams["pose"].stamps) < 40 and len(pairing) <= 1


def test_revisits_are_returns_after_leaving() -> None:
    # out along x, back along the same line 0.2 m aside, then standing still at the end
    out = np.stack([np.arange(0.0, 20.0, 1.0), np.zeros(20), np.zeros(20)], axis=1)
    back = out[::-1] + [0.0, 0.2, 0.0]
    still = np.repeat(back[-1:], 5, axis=0)
    truth = revisits_from_positions(np.vstack([out, back, still]), radius_m=1.5)
    rows = {int(q): truth.matches[truth.indptr[i]:truth.indptr[i + 1]].tolist() for i, q in enumerate(truth.queries)}
    assert rows[3] == [] and rows[19] == []  # going out: nothing seen before that was left
    assert rows[20] == [] and rows[21] == []  # the turn: frames 18, 19 were never left (2 x radius)
    assert rows[30] == [8, 9, 10]  # back at x = 9: the outward frames within 1.5 m
    assert rows[40] == [0, 1] and rows[44] == [0, 1]  # standing still counts the start, not itself
    assert 40 not in rows[44]


def test_the_tf_tree_chains_static_and_dynamic_transforms_at_a_time() -> None:
    tree = TransformTree()
    mount = se3_from_euler(np.array([0.1, 0.0, 0.3]), np.array([0.0, 0.0, np.pi / 2]))
    tree.add("base_link", "camera", 0, mount, static=True)
    tree.add("/map", "odom", 0, np.eye(4), static=True)
    for k in range(10):
        tree.add("odom", "base_link", k * 100 * MS, se3_from_euler(np.array([k * 1.0, 0, 0]), np.zeros(3)))
    pose = tree.lookup("map", "camera", 400 * MS + 3 * MS, tolerance=10 * MS)
    assert pose is not None and np.allclose(pose, se3_from_euler(np.array([4.0, 0, 0]), np.zeros(3)) @ mount)
    assert tree.lookup("map", "camera", 450 * MS, tolerance=10 * MS) is None  # no odom edge near that time
    inverse = tree.lookup("camera", "map", 400 * MS, tolerance=0)
    assert inverse is not None and np.allclose(inverse @ pose, np.eye(4))
    assert tree.lookup("map", "nowhere", 0, tolerance=10 * MS) is None
    tree.forget_before(800 * MS)
    assert tree.lookup("map", "camera", 200 * MS, tolerance=10 * MS) is None
    assert tree.lookup("map", "camera", 900 * MS, tolerance=0) is not None


def test_pairing_refuses_a_negative_tolerance() -> None:
    with pytest.raises(ValueError):
        StreamPairing(["depth"], tolerance_ns=-1)
