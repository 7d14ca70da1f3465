"""bow_bayes on real images (loop10, Nordland as one stream), its sources, and bad input at the CLI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront.errors import DataError
from slamfront.mcaplog.reader import read_messages
from slamfront.messages import LoopResult
from slamfront.recipe import build_pipeline, load_recipe, recipes_dir
from slamfront.runtime import run_pipeline
from slamfront_plugins.sources.image_folder import ImageFolder
from slamfront_plugins.sources.nordland_stream import NordlandStream

# By inspection of ../shared/data/images/loop10 (a camera circling a desk): 10.png is
# taken from where 1.png was (same monitor, keyboard, phone, tape, cans); 5/6 and 7/8
# overlap but are consecutive views, not revisits. So frame 9 revisits frame 0, and no
# other frame revisits anything.
LOOP10_REVISITS = {9: [0]}


def _results(log: Path) -> dict[int, LoopResult]:
    return {
        r.frame: r
        for r in (LoopResult.from_json(m.data) for m in read_messages(log, ["/loop_detector/loop_result"]))
    }


@pytest.mark.parametrize("rule", ["greedy", "nndr"])
def test_loop10_the_revisit_is_the_surest_loop(rule: str, tmp_path: Path, shared_data: Path) -> None:
    recipe, path = load_recipe(
        recipes_dir() / "loop10_bow.yaml",
        [f"loop_detector.params.vocabulary_update={rule}", f"loop_detector.params.compare_rules={rule == 'greedy'}"],
    )
    truth = build_pipeline(recipe, str(path)).source.loop_ground_truth()
    assert truth is not None
    assert {int(q): truth.matches[truth.indptr[k] : truth.indptr[k + 1]].tolist()
            for k, q in enumerate(truth.queries) if truth.indptr[k + 1] > truth.indptr[k]} == LOOP10_REVISITS
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False)
    metrics = result.metrics
    answers = _results(result.log_path)
    assert answers[9].match == 0 and answers[9].candidates[0] == 0
    # no other frame is as sure of a loop as frame 9 is of its true one
    assert all(a.confidence < answers[9].confidence for f, a in answers.items() if f != 9)
    assert metrics["recall_at_100p"] == 1.0 and metrics["auc_pr"] == 1.0
    for key in ("recall_at_100p", "auc_pr", "n_queries", "n_searches", "n_places_reference", "n_places_query",
                "seconds", "frames_per_second", "bow_vocabulary_size", "bow_wm_size_max", "bow_processing_ms_p99"):
        assert key in json.loads(result.metrics_path.read_text()), key
    report = result.report_path.read_text()
    for figure in ("bow_vocabulary.png", "bow_quantisation.png", "bow_posterior.png", "bow_memory.png", "pr.png"):
        assert (tmp_path / figure).stat().st_size > 5000 and figure in report
    if rule == "greedy":
        # seed fig. 6 on real images: the greedy words quantise far closer; fig. 4: sizes comparable
        assert metrics["bow_mean_quantisation_error"] < 0.6 * metrics["bow_other_mean_quantisation_error"]
        assert 0.8 < metrics["bow_vocabulary_size"] / metrics["bow_other_vocabulary_size"] < 1.3


def test_nordland_stream_source(shared_data: Path) -> None:
    source = NordlandStream(NordlandStream.Config(root=shared_data / "nordland", start=100, step=2, limit=20))
    frames = list(source.frames())
    assert len(frames) == len(source) == 40
    assert frames[0].name == "summer/images-01010.png" and frames[20].name == "winter/images-01010.png"
    assert frames[0].image.shape == (32, 64, 3) and {f.traversal for f in frames} == {"stream"}
    assert [f.sequence_index for f in frames] == list(range(40))
    truth = source.loop_ground_truth()
    rows = {int(q): truth.matches[truth.indptr[k] : truth.indptr[k + 1]].tolist() for k, q in enumerate(truth.queries)}
    assert all(rows[f] == [] for f in range(20))  # the first season revisits nothing
    assert rows[20] == [0, 1, 2, 3] and rows[30] == [7, 8, 9, 10, 11, 12, 13] and rows[39] == [16, 17, 18, 19]


def test_nordland_seasons_must_be_frame_aligned(tmp_path: Path) -> None:
    for season, names in (("summer", ["a.png", "b.png"]), ("winter", ["a.png", "c.png"])):
        (tmp_path / season).mkdir()
        for name in names:
            cv2.imwrite(str(tmp_path / season / name), np.zeros((8, 8), np.uint8))
    with pytest.raises(DataError, match="do not hold the same frame names"):
        len(NordlandStream(NordlandStream.Config(root=tmp_path)))


def test_nordland_bow_recipe_runs_on_a_stretch_with_dark_frames(tmp_path: Path, shared_data: Path) -> None:
    """Summer frames 0-16 are black (the route start): 'no answer', never a crash or a guess."""
    recipe, path = load_recipe(recipes_dir() / "nordland_bow.yaml", ["source.params.limit=40"])
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False)
    answers = _results(result.log_path)
    assert len(answers) == 80
    assert all(answers[f].match == -1 and "features" in answers[f].reason for f in range(10))
    assert result.metrics["n_frames_without_features"] >= 10


def test_image_folder_loop_labels(tmp_path: Path, shared_data: Path) -> None:
    labels = tmp_path / "loops.txt"
    labels.write_text("# same places\n1.png 10.png\n\n3.png 4.png 5.png  # a group of three\n")
    folder = shared_data / "images/loop10"
    source = ImageFolder(ImageFolder.Config(folder=folder, loops=[["2.png", "9.png"]], loops_file=labels))
    truth = source.loop_ground_truth()
    rows = {int(q): truth.matches[truth.indptr[k] : truth.indptr[k + 1]].tolist() for k, q in enumerate(truth.queries)}
    assert rows[9] == [0] and rows[8] == [1] and rows[3] == [2] and rows[4] == [2, 3] and rows[0] == []
    assert ImageFolder(ImageFolder.Config(folder=folder)).loop_ground_truth() is None
    bad = ImageFolder(ImageFolder.Config(folder=folder, loops=[["1.png", "11.png"]]))
    with pytest.raises(DataError, match=r"source.params.loops\[0\]: 11.png not among the frames"):
        bad.loop_ground_truth()
    labels.write_text("1.png\n")
    with pytest.raises(DataError, match=r"loops.txt:1: a loop group needs at least two"):
        ImageFolder(ImageFolder.Config(folder=folder, loops_file=labels)).loop_ground_truth()


def _bow_recipe(folder: Path, **detector: object) -> dict:
    return {
        "name": "bow",
        "source": {"plugin": "image_folder", "params": {"folder": str(folder)}},
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb"}},
        "loop_detector": {"plugin": "bow_bayes", "params": detector},
        "eval": {"plots": False},
    }


def test_black_frames_run_to_the_end_with_no_answer(tmp_path: Path, cli, write_recipe) -> None:
    folder = tmp_path / "black"
    folder.mkdir()
    for k in range(6):
        cv2.imwrite(str(folder / f"{k}.png"), np.zeros((48, 64), np.uint8) + (0 if k % 2 else 255))
    code, _, err = cli("run", write_recipe(_bow_recipe(folder)), "-o", tmp_path / "out", "-q")
    assert code == 0, err
    answers = _results(tmp_path / "out" / "run.mcap")
    assert len(answers) == 6 and all(a.match == -1 and a.reason == "no features" for a in answers.values())


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"loop_detector": {"descriptor_type": "surf"}}, "loop_detector.params.descriptor_type: SURF is patented"),
        ({"descriptor": {"descriptor": "surf"}}, "descriptor.params.descriptor: SURF is patented"),
        ({"loop_detector": {"descriptor_type": "sift"}}, "the vocabulary is built for sift descriptors .* gives orb"),
        ({"loop_detector": {"nd_low": 50, "nd_high": 10}}, "nd_low .* must not exceed nd_high"),
    ],
    ids=["surf-detector", "surf-descriptor", "wrong-descriptor", "thresholds"],
)
def test_bad_recipes_get_one_clear_line(change: dict, message: str, tmp_path: Path, cli, write_recipe) -> None:
    recipe = _bow_recipe(tmp_path)
    for stage, params in change.items():
        recipe[stage]["params"].update(params)
    code, _, err = cli("run", write_recipe(recipe), "-o", tmp_path / "out", "-q")
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert re.search(message, err), err
