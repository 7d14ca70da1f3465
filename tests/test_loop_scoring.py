"""The loop evaluation's scoring rules on a hand-built sequence: frame vs place, unsearched frames."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from slamfront.core.loops import LoopGroundTruth
from slamfront.evaluation.base import EvaluationContext
from slamfront.evaluation.loops import LoopClosureEvaluation
from slamfront.messages import LoopResult
from slamfront.recipe import EvalOptions

# A stream whose frames 10..13 revisit frames 1..7. The detector merged frames 2, 3, 4 into
# one place it reports as frame 3 (the middle); frame 12 was merged into frame 11's place
# and repeated its answer without searching.
TRUTH = LoopGroundTruth.from_rows(
    np.array([10, 11, 12, 13]),
    [np.array([1, 2]), np.array([2, 3]), np.array([5, 6]), np.array([6, 7])],
)
PLACE = np.array([2, 3, 4])
RESULTS = [
    # frame 10 sees frames 1-2: the place covers 2, its middle frame 3 does not
    LoopResult(frame=10, match=3, confidence=0.9, accepted=True, match_frames=PLACE),
    LoopResult(frame=11, match=3, confidence=0.8, accepted=True, match_frames=PLACE),
    # frame 12 repeats frame 11's answer, which is wrong where it stands
    LoopResult(frame=12, match=3, confidence=0.95, accepted=True, match_frames=PLACE, searched=False),
    # a detector without places: the match frame alone is scored
    LoopResult(frame=13, match=7, confidence=0.7, accepted=True),
]


def _scores(tmp_path: Path, **options: object) -> tuple[dict, str]:
    evaluation = LoopClosureEvaluation()
    for result in RESULTS:
        evaluation.observe("loop_detector", result)
    source = SimpleNamespace(loop_ground_truth=lambda: TRUTH, config=SimpleNamespace())
    context = EvaluationContext(
        source=source,  # type: ignore[arg-type]
        out_dir=tmp_path,
        options=EvalOptions(**{"plots": False, **options}),  # type: ignore[arg-type]
        statistics={},
        plugin_names={"loop_detector": "hand"},
    )
    report = evaluation.finish(context)
    assert report is not None
    return report.metrics, report.markdown


def test_frame_scoring_is_the_default_and_counts_every_frame(tmp_path: Path) -> None:
    metrics, markdown = _scores(tmp_path)
    assert metrics["loop_scoring"] == "frame" and metrics["unsearched_frames"] == "score"
    assert metrics["n_queries"] == 4 and metrics["n_queries_excluded"] == 0
    # by confidence: 12 (wrong), 10 (wrong: 3 is not 1 or 2), 11 (right), 13 (right)
    assert metrics["recall_at_100p"] == 0.0
    assert metrics["auc_pr"] == pytest.approx(0.25 * 1 / 3 + 0.25 * 2 / 4)
    assert "frame scoring" in markdown and "every frame is scored" in markdown


def test_place_scoring_counts_a_match_to_any_frame_of_the_place(tmp_path: Path) -> None:
    metrics, markdown = _scores(tmp_path, loop_scoring="place")
    # 10 is now right (frame 2 is in the place); 12 still opens with a false positive
    assert metrics["recall_at_100p"] == 0.0
    assert metrics["auc_pr"] == pytest.approx(0.25 * 1 / 2 + 0.25 * 2 / 3 + 0.25 * 3 / 4)
    assert "place scoring" in markdown


def test_unsearched_frames_can_be_left_out(tmp_path: Path) -> None:
    metrics, markdown = _scores(tmp_path, loop_scoring="place", unsearched_frames="exclude", plots=True)
    assert metrics["n_queries"] == 3 and metrics["n_queries_excluded"] == 1
    assert metrics["n_queries_with_true_match"] == 3
    assert metrics["recall_at_100p"] == 1.0 and metrics["auc_pr"] == pytest.approx(1.0)
    assert "left out (1 frames)" in markdown
    frame_only, _ = _scores(tmp_path, unsearched_frames="exclude")
    assert frame_only["recall_at_100p"] == 0.0  # frame 10's middle-frame answer is still wrong


def test_place_correctness_in_the_core() -> None:
    got = TRUTH.is_correct_place(np.array([10, 10, 13, 13, 99]), np.array([3, -1, 7, 3, 3]),
                                 [PLACE, PLACE, None, np.array([], np.int64), PLACE])
    assert got.tolist() == [True, False, True, False, False]
    assert TRUTH.subset(np.array([True, False, False, True])).queries.tolist() == [10, 13]
