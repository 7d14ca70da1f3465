"""Paired-traversal sources: dataset layouts, selection, Rodrigues 2019's experiments 2 and 3, bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront import DataError
from slamfront.errors import RecipeError
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.sources.paired_datasets import GardensPoint, Nordland, PairedFolders, UofA, VprBench


def _write_images(folder: Path, names: list[str], seed: int = 0, size: tuple[int, int] = (24, 32)) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 256, (*size, 3), dtype=np.uint8))


def _truth_rows(source) -> list[list[int]]:  # type: ignore[no-untyped-def]
    truth = source.loop_ground_truth()
    return [truth.matches[truth.indptr[i] : truth.indptr[i + 1]].tolist() for i in range(len(truth))]


# --- layouts ------------------------------------------------------------------------------------


def test_gardens_point_layout_with_an_extra_archive_level(tmp_path: Path) -> None:
    for walk in ("day_left", "day_right", "night_right"):
        _write_images(tmp_path / "GardensPoint" / walk, [f"Image{i:03d}.jpg" for i in range(12)])
    source = GardensPoint(GardensPoint.Config(root=tmp_path, reference="day_right", tolerance=2))
    frames = list(source.frames())
    assert len(frames) == len(source) == 24
    assert [f.traversal for f in frames] == ["reference"] * 12 + ["query"] * 12
    assert frames[0].name == "Image000.jpg" and frames[12].name == "Image000.jpg"
    assert "day_right" in str(source.plan[0][0].path) and "night_right" in str(source.plan[1][0])
    assert _truth_rows(source)[5] == [3, 4, 5, 6, 7]
    assert np.all(np.diff([f.timestamp for f in frames]) > 0)


def test_uofa_layout_sorts_numbered_files_numerically(tmp_path: Path) -> None:
    names = [f"{i}.jpg" for i in range(1, 13)]
    _write_images(tmp_path / "day_evening" / "day", names)
    _write_images(tmp_path / "day_evening" / "evening", names, seed=1)
    source = UofA(UofA.Config(root=tmp_path))
    assert [f.name for f in source.frames()][:12] == names  # 2.jpg before 10.jpg


def test_vpr_bench_layout_and_ground_truth(tmp_path: Path) -> None:
    _write_images(tmp_path / "ref", [f"{i}.jpg" for i in range(10)])
    _write_images(tmp_path / "query", [f"{i}.jpg" for i in range(4)], seed=2)
    table = np.empty((3, 2), dtype=object)
    table[0] = [0, [2, 3]]
    table[1] = [2, [7]]
    table[2] = [3, []]
    np.save(tmp_path / "ground_truth_new.npy", table)
    source = VprBench(VprBench.Config(root=tmp_path))
    # query frames are 10..13; query 1 is not in the file: no true match
    assert _truth_rows(source) == [[2, 3], [], [7], []]
    widened = VprBench(VprBench.Config(root=tmp_path, tolerance=1))
    assert _truth_rows(widened)[2] == [6, 7, 8]


def test_two_folders_paired_by_position_or_by_csv(tmp_path: Path) -> None:
    _write_images(tmp_path / "ref", [f"r{i:02d}.png" for i in range(8)])
    _write_images(tmp_path / "qry", [f"q{i:02d}.png" for i in range(5)], seed=3)
    (tmp_path / "pairs.csv").write_text("query,reference\nq00.png,r03.png\n2,6\n2,0\n# a comment\n")
    source = PairedFolders(PairedFolders.Config(
        reference_folder=tmp_path / "ref", query_folder=tmp_path / "qry", pairs=tmp_path / "pairs.csv", tolerance=0,
    ))
    assert _truth_rows(source) == [[3], [], [0, 6], [], []]
    one_based = tmp_path / "one.csv"
    one_based.write_text("1,1\n5,8\n")
    source = PairedFolders(PairedFolders.Config(
        reference_folder=tmp_path / "ref", query_folder=tmp_path / "qry", pairs=one_based, index_base=1, tolerance=0,
    ))
    assert _truth_rows(source) == [[0], [], [], [], [7]]


def test_nordland_pairs_seasons_by_frame_name(shared_data: Path) -> None:
    source = Nordland(Nordland.Config(start=100, step=10, limit=30))
    references, queries, places = source.plan
    assert len(references) == len(queries) == 30
    assert references[0].path.name == queries[0].name == "images-01010.png"
    assert references[1].path.name == "images-01110.png"
    truth = source.loop_ground_truth()
    assert truth.queries.tolist() == list(range(30, 60))
    assert _truth_rows(source)[10] == [7, 8, 9, 10, 11, 12, 13]  # zeta 3 counted in selected frames
    frame = next(iter(source.frames()))
    assert frame.image.shape == (32, 64, 3) and frame.traversal == "reference"


# --- experiments --------------------------------------------------------------------------------


def _folders(tmp_path: Path, n: int = 20) -> dict:
    _write_images(tmp_path / "ref", [f"{i:03d}.png" for i in range(n)])
    _write_images(tmp_path / "qry", [f"{i:03d}.png" for i in range(n)], seed=1)
    return {"reference_folder": tmp_path / "ref", "query_folder": tmp_path / "qry", "tolerance": 1}


def test_experiment_3_moves_a_block_to_the_end_and_the_truth_follows(tmp_path: Path) -> None:
    source = PairedFolders(PairedFolders.Config(**_folders(tmp_path), experiment="reordered", block_start=5, block_length=4))
    order = [item.path.name for item in source.plan[0]]
    assert order[:5] == [f"{i:03d}.png" for i in range(5)]
    assert order[5:7] == ["009.png", "010.png"] and order[-4:] == ["005.png", "006.png", "007.png", "008.png"]
    rows = _truth_rows(source)
    # query 6 shows place 6, now at stream positions 16..19: 5 -> 16, 6 -> 17, 7 -> 18
    assert rows[6] == [16, 17, 18]
    assert rows[4] == [3, 4, 16]  # place 5 moved away with the block
    assert rows[9] == [5, 6, 19]  # place 8 (block end, now at 19), 9 and 10 (now at 5 and 6)


def test_experiment_2_replaces_a_block_with_another_dataset(tmp_path: Path) -> None:
    _write_images(tmp_path / "other", [f"x{i}.png" for i in range(6)], seed=9, size=(48, 64))
    source = PairedFolders(PairedFolders.Config(
        **_folders(tmp_path), experiment="replaced", block_start=8, block_length=6, replacement_folder=tmp_path / "other",
    ))
    frames = list(source.frames())
    assert [f.name for f in frames[8:14]] == [f"x{i}" + ".png" for i in range(6)]
    assert frames[8].image.shape == frames[0].image.shape  # resized to the reference size
    rows = _truth_rows(source)
    assert rows[10] == [] and rows[8] == [7] and rows[13] == [14]
    assert source.loop_ground_truth().has_true_match().sum() == 20 - 4


def test_experiment_2_defaults_to_the_synthetic_world_in_grey_for_grey_references(shared_data: Path) -> None:
    source = Nordland(Nordland.Config(limit=40, experiment="replaced", block_start=10, block_length=3))
    frames = [f for f, _ in zip(source.frames(), range(14))]
    foreign = frames[10].image
    assert frames[10].name == "synthetic-00000" and foreign.shape == (32, 64, 3)
    assert np.array_equal(foreign[..., 0], foreign[..., 1]) and foreign.std() > 5


def test_block_drawn_from_the_seed_fits_and_is_reproducible(tmp_path: Path) -> None:
    config = dict(**_folders(tmp_path, 40), experiment="reordered", block_length=8)
    a = PairedFolders(PairedFolders.Config(**config, seed=1)).block(40)
    assert a == PairedFolders(PairedFolders.Config(**config, seed=1)).block(40)
    assert 4 <= a[0] and a[0] + a[1] <= 36
    with pytest.raises(DataError, match="runs past"):
        PairedFolders(PairedFolders.Config(**config, block_start=35)).plan  # noqa: B018


# --- bad input ----------------------------------------------------------------------------------


def test_mismatched_traversal_lengths_are_refused_before_the_first_frame(tmp_path: Path, write_recipe, cli) -> None:
    _write_images(tmp_path / "ref", [f"{i}.png" for i in range(6)])
    _write_images(tmp_path / "qry", [f"{i}.png" for i in range(5)])
    recipe = write_recipe({
        "name": "bad", "source": {"plugin": "paired_folders", "params": {
            "reference_folder": str(tmp_path / "ref"), "query_folder": str(tmp_path / "qry")}},
        "descriptor": {"plugin": "rst_shelo"},
    })
    code, _, err = cli("run", recipe, "-o", tmp_path / "out", "-q")
    assert code == 2 and "the reference has 6 images but the query 5" in err
    assert "Traceback" not in err


def test_ground_truth_file_longer_than_the_queries_names_the_file(tmp_path: Path) -> None:
    _write_images(tmp_path / "ref", ["0.jpg", "1.jpg"])
    _write_images(tmp_path / "query", ["0.jpg"])
    np.save(tmp_path / "ground_truth_new.npy", np.array([[0, [1]], [1, [0]]], dtype=object))
    with pytest.raises(DataError, match="ground_truth_new.npy: 2 ground-truth rows but only 1 query images"):
        VprBench(VprBench.Config(root=tmp_path)).plan  # noqa: B018
    (tmp_path / "pairs.csv").write_text("0,7\n")
    with pytest.raises(DataError, match="pairs.csv:1: reference '7' is not an image name or a position"):
        config = PairedFolders.Config(reference_folder=tmp_path / "ref", query_folder=tmp_path / "query",
                                      pairs=tmp_path / "pairs.csv")
        PairedFolders(config).plan  # noqa: B018


def test_a_season_missing_a_frame_is_named(tmp_path: Path) -> None:
    _write_images(tmp_path / "summer", ["images-00010.png", "images-00020.png"])
    _write_images(tmp_path / "winter", ["images-00010.png", "images-00030.png"])
    with pytest.raises(DataError, match="winter/images-00020.png: missing"):
        Nordland(Nordland.Config(root=tmp_path)).plan  # noqa: B018


def _corrupt_query_recipe(tmp_path: Path, unreadable: str) -> dict:
    _write_images(tmp_path / "ref", [f"{i:02d}.png" for i in range(12)], size=(32, 64))
    _write_images(tmp_path / "qry", [f"{i:02d}.png" for i in range(12)], seed=1, size=(32, 64))
    (tmp_path / "qry" / "05.png").write_bytes(b"\x89PNG not really")
    (tmp_path / "qry" / "07.png").write_bytes(b"")  # zero-size file
    return {
        "name": "corrupt",
        "source": {"plugin": "paired_folders", "params": {
            "reference_folder": str(tmp_path / "ref"), "query_folder": str(tmp_path / "qry"),
            "unreadable_images": unreadable}},
        "descriptor": {"plugin": "rst_shelo"},
        "place_map": {"plugin": "hierarchical", "params": {"similarity_threshold": 0.999}},
        "loop_detector": {"plugin": "hierarchical_sequence", "params": {"rho": 2}},
        "log": {"images": False},
    }


def test_a_corrupt_query_image_stops_the_run_with_its_name(tmp_path: Path, write_recipe, cli) -> None:
    recipe = write_recipe(_corrupt_query_recipe(tmp_path, "error"))
    code, _, err = cli("run", recipe, "-o", tmp_path / "out", "-q")
    assert code == 2 and "qry/05.png: not a readable image" in err and "Traceback" not in err
    from slamfront.mcaplog.reader import summarize

    assert summarize(tmp_path / "out" / "run.mcap").complete  # the log written so far is kept, readable


def test_unreadable_images_can_become_blank_unanswered_frames(tmp_path: Path) -> None:
    recipe = parse_recipe(_corrupt_query_recipe(tmp_path, "blank"), "corrupt")
    result = run_pipeline(build_pipeline(recipe, "corrupt"), "corrupt", tmp_path / "out", progress=False)
    assert result.metrics["n_queries"] == 12 and result.metrics["n_not_reported"] == 0
    from slamfront.mcaplog.reader import read_messages

    answers = {m.decoded.frame: m.decoded for m in read_messages(result.log_path, ["/loop_detector/loop_result"])}
    assert answers[12 + 5].match == -1 and answers[12 + 7].match == -1
    assert answers[12 + 5].reason.startswith("featureless")


def test_zero_size_images_and_unknown_params_are_clear(tmp_path: Path) -> None:
    _write_images(tmp_path / "ref", ["a.png"])
    (tmp_path / "ref" / "b.png").write_bytes(b"")
    _write_images(tmp_path / "qry", ["a.png", "b.png"])
    source = PairedFolders(PairedFolders.Config(reference_folder=tmp_path / "ref", query_folder=tmp_path / "qry"))
    with pytest.raises(DataError, match="ref/b.png: empty file"):
        list(source.frames())
    with pytest.raises(RecipeError, match="replacement_folder is only used by experiment: replaced"):
        build_pipeline(parse_recipe({"name": "x", "source": {"plugin": "paired_folders", "params": {
            "reference_folder": "a", "query_folder": "b", "replacement_folder": "c"}}}, "r"), "r")
