"""What the report plots mark: spikes, route order, operating points, accepted vs rejected."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamfront.evaluation.frames import FrameOverview
from slamfront.messages import FrameInfo
from slamfront.report import plots


def test_a_spike_is_far_above_the_typical_error() -> None:
    errors = np.r_[np.full(50, 0.1) + np.linspace(0, 0.02, 50), 1.5, np.nan]
    threshold = plots.spike_threshold(errors)
    assert 0.12 < threshold < 1.5 and np.sum(errors > threshold) == 1
    assert plots.spike_threshold(np.array([1.0, 2.0])) == np.inf  # too few to say


def test_a_shuffled_drive_is_drawn_in_route_order() -> None:
    overview = FrameOverview()
    order = np.random.default_rng(0).permutation(30)
    for frame, place in enumerate(order):
        pose = np.eye(4)
        pose[:3, 3] = [place, 0.5 * place, 0.0]
        overview.observe("frames", FrameInfo(frame=frame, timestamp=float(frame), traversal="query",
                                             sequence_index=int(place), name="", width=1, height=1, pose=pose))
    path = overview._paths()["query"]
    assert np.array_equal(path[:, 0], np.arange(30))


def test_the_plots_draw_their_marks(tmp_path: Path) -> None:
    curve = (np.linspace(0.1, 1, 10), np.linspace(1, 0.5, 10))
    assert plots.pr_curves({"d": curve}, tmp_path / "pr.png", points={"op": (0.9, 0.6), "verified": (0.5, 1.0)}).is_file()
    query = np.arange(20, dtype=float)
    accepted = query % 2 == 0
    for confidence in (np.full(20, 0.2), np.linspace(0.05, 0.3, 20)):  # one value, or a narrow range
        assert plots.match_plot(query, query.copy(), confidence, query < 15, query - 1, query + 1,
                                tmp_path / "m.png", accepted=accepted).is_file()
    positions = np.c_[np.arange(10.0), np.zeros(10), np.zeros(10)]
    assert plots.trajectories_2d({"path": positions}, tmp_path / "t.png",
                                 links={"loops": (np.stack([positions[:3], positions[5:8]], 1), "tab:green")},
                                 flagged={"rejected": (positions[:2], "X", "tab:red")}).is_file()
    errors = np.r_[np.full(9, 0.1), 2.0]
    assert plots.error_along(np.arange(10.0), errors, tmp_path / "e.png", missing=np.array([3.5])).is_file()
    assert plots.pair_errors(np.arange(10), errors, errors, np.full(10, 0.8), tmp_path / "p.png",
                             outcomes=["aligned"] * 8 + ["fallback", "rejected"]).is_file()
