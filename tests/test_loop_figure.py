"""The run's path figure tells the loop closures apart: what the back end verified, what it
rejected, what no back end checked, and the true revisits nobody closed."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from slamfront.core.loops import LoopGroundTruth
from slamfront.evaluation.frames import FrameOverview
from slamfront.messages import FrameInfo, LoopResult
from slamfront_plugins.backends.messages import LoopConstraint


def _overview(with_backend: bool) -> tuple[FrameOverview, SimpleNamespace]:
    overview = FrameOverview()
    for frame in range(10):  # two laps of 5 places, 1 m apart
        pose = np.eye(4)
        pose[0, 3] = frame % 5
        overview.observe("frames", FrameInfo(frame=frame, timestamp=float(frame), traversal="stream",
                                             sequence_index=frame, name=str(frame), width=4, height=4, pose=pose))
    # frames 5-9 revisit 0-4; answers: 5 right, 6 right, 7 wrong, 8 right; 9 unanswered
    for frame, match in ((5, 0), (6, 1), (7, 3), (8, 3)):
        overview.observe("loop_detector", LoopResult(frame=frame, match=match, confidence=0.9, accepted=True))
    if with_backend:  # 5 verified, 6 rejected, 7 rejected (wrong), 8 never checked
        for frame, match, added in ((5, 0, True), (6, 1, False), (7, 3, False)):
            overview.observe("backend", LoopConstraint(frame=frame, match=match, added=added, reason=""))
    truth = LoopGroundTruth.from_rows(np.arange(5, 10), [np.array([k]) for k in range(5)])
    context = SimpleNamespace(source=SimpleNamespace(loop_ground_truth=lambda: truth), out_dir=Path("."))
    return overview, context


def _counts(dots: dict) -> dict[str, int]:  # type: ignore[type-arg]
    return {label: len(points) for label, (points, _, _) in dots.items()}


def test_with_a_back_end_verified_rejected_unchecked_and_missed_are_apart() -> None:
    overview, context = _overview(with_backend=True)
    links, dots = overview._loop_links(context)
    assert _counts(dots) == {
        "verified by the back end, correct": 1,
        "accepted, not checked by the back end, correct": 1,
        "rejected by the back end, correct": 1,
        "rejected by the back end, wrong": 1,
        "missed (a true revisit with no correct closure)": 2,  # 9 unanswered, 7 answered wrong
    }
    (wrong_kept,) = links.values()
    assert len(wrong_kept[0]) == 0  # the one wrong closure was rejected: no line dominates the figure


def test_without_a_back_end_a_wrong_accepted_closure_is_a_line() -> None:
    overview, context = _overview(with_backend=False)
    links, dots = overview._loop_links(context)
    assert _counts(dots) == {"accepted, correct": 3, "accepted, wrong": 1,
                             "missed (a true revisit with no correct closure)": 2}
    (wrong_kept,) = links.values()
    assert len(wrong_kept[0]) == 1
