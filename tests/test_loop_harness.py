"""The loop-closure harness end to end: Nordland, several tolerances, search space, retrieval."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from slamfront.recipe import build_pipeline, load_recipe
from slamfront.runtime import run_pipeline
from tests.helpers import small_synthetic_recipe

DESIGN_KEYS = ("recall_at_100p", "auc_pr", "n_queries", "n_searches", "n_places_reference", "n_places_query",
               "seconds", "frames_per_second")


def test_nordland_segment_through_the_whole_harness(shared_data: Path, tmp_path: Path) -> None:
    """Real data, frames 0-399 of both seasons: measured 0.80 recall at 100 % precision, AUC 0.89."""
    recipe, path = load_recipe("nordland_hsl", ["source.params.limit=400", "log.images=false"])
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path, progress=False)
    metrics = json.loads(result.metrics_path.read_text())
    for key in DESIGN_KEYS:
        assert key in metrics, key
    assert metrics["n_queries"] == 400 and metrics["n_frames_reference"] == 400
    assert metrics["recall_at_100p"] >= 0.6 and metrics["auc_pr"] >= 0.75
    # zeta = 1 is stricter than zeta = 3
    assert metrics["auc_pr_zeta1"] <= metrics["auc_pr"] and "recall_at_100p_zeta1" in metrics
    # the map is smaller than the traversal, and far fewer searches than queries (seed Table 4.4)
    assert metrics["n_places_reference"] < 400 and metrics["n_searches"] < metrics["n_places_query"] / 4
    assert 0.3 <= metrics["retrieval_recall_at_20"] <= 1.0 and len(metrics["retrieval_recall_curve"]) == 20
    report = result.report_path.read_text()
    assert "Search space (Rodrigues 2019 Table 4.4)" in report and "retrieval.png" in report
    for figure in ("pr.png", "matches.png", "retrieval.png"):
        assert (tmp_path / figure).stat().st_size > 1000


def test_detectors_without_places_fill_the_search_space_with_frames(tmp_path: Path, write_recipe) -> None:
    path = write_recipe({**small_synthetic_recipe(frames_per_traversal=20), "eval": {"plots": False, "tolerances": [0, 1]}})
    recipe, _ = load_recipe(path)
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path / "run", progress=False)
    metrics = result.metrics
    assert metrics["n_places_reference"] == 20 and metrics["n_places_query"] == 20 and metrics["n_searches"] == 20
    assert metrics["recall_at_1_zeta0"] <= metrics["recall_at_1_zeta1"] <= metrics["recall_at_1"]
    assert "| 20 / 20 | 20 | 20 | 20 |" in result.report_path.read_text()


def test_tolerances_a_source_cannot_change_are_reported_not_invented(tmp_path: Path, write_recipe) -> None:
    raw = small_synthetic_recipe(mode="stream", laps=2, frames_per_traversal=15)
    path = write_recipe({**raw, "eval": {"plots": False, "tolerances": [1]}})
    recipe, _ = load_recipe(path)
    result = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path / "run", progress=False)
    assert "recall_at_100p_zeta1" not in result.metrics
    assert "cannot be scored at tolerance 1" in result.report_path.read_text()


def test_retrieval_command_compares_descriptor_settings(cli, tmp_path: Path, write_recipe) -> None:
    raw = small_synthetic_recipe(frames_per_traversal=25)
    raw["descriptor"] = {"plugin": "rst_shelo"}
    path = write_recipe(raw)
    code, out, err = cli("retrieval", path, "--compare", "descriptor.params.preprocess=true,false", "--max-k", "5",
                         "-o", tmp_path / "ret")
    assert code == 0, err
    assert "| psi | preprocess=true | preprocess=false |" in out
    curves = json.loads((tmp_path / "ret" / "retrieval.json").read_text())
    assert set(curves) == {"preprocess=true", "preprocess=false"} and len(curves["preprocess=true"]) == 5
    assert all(a <= b for a, b in zip(curves["preprocess=true"], curves["preprocess=true"][1:]))  # grows with psi
    assert (tmp_path / "ret" / "retrieval.png").exists()
    code, _, err = cli("retrieval", path, "--compare", "descriptor.params.preprocess", "-o", tmp_path / "x")
    assert code == 2 and "expected KEY=V1,V2" in err


@pytest.mark.parametrize("name", ["nordland_hsl", "nordland_hsl_exp2", "nordland_hsl_exp3", "synthetic_hsl"])
def test_hierarchical_recipes_use_the_seed_parameters(name: str) -> None:
    recipe, _ = load_recipe(name)
    detector = recipe.loop_detector.params  # type: ignore[union-attr]
    assert (detector.get("rho", 5), detector.get("psi", 10), detector.get("alpha", 5)) == (5, 10, 5)
    assert recipe.source.params.get("tolerance", 3) == 3 and recipe.eval.tolerances == [1]


def test_a_replay_scores_the_extra_tolerances_too(tmp_path: Path, write_recipe) -> None:
    from slamfront.replay import replay_log

    path = write_recipe({**small_synthetic_recipe(frames_per_traversal=20), "eval": {"plots": False, "tolerances": [1]}})
    recipe, _ = load_recipe(path)
    original = run_pipeline(build_pipeline(recipe, str(path)), str(path), tmp_path / "run", progress=False)
    replay = replay_log(original.log_path, tmp_path / "replay", progress=False)
    for key in ("recall_at_100p_zeta1", "auc_pr_zeta1", "recall_at_1_zeta1"):
        assert replay.metrics[key] == original.metrics[key]
