"""`slamfront compare`: several recipes, one harness, one report."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from tests.helpers import small_synthetic_recipe


def _recipes(tmp_path: Path) -> list[Path]:
    paths = []
    for name, descriptor, detector in (
        ("cmp_seqslam", {"plugin": "seqslam_thumbnail", "params": {"width": 64, "height": 48}},
         {"plugin": "seqslam", "params": {"ds": 6}}),
        ("cmp_nn", {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
         {"plugin": "nearest_neighbour", "params": {}}),
    ):
        raw = small_synthetic_recipe()
        raw.update(name=name, descriptor=descriptor, loop_detector=detector)
        raw["eval"] = {"plots": True}
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(raw))
        paths.append(path)
    return paths


def test_compare_runs_every_recipe_and_writes_one_report(cli, tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    code, stdout, stderr = cli("compare", *_recipes(tmp_path), "-o", out, "--workers", "1", "-q")
    assert code == 0, stderr
    assert "comparison:" in stdout
    report = (out / "comparison.md").read_text()
    assert "| cmp_seqslam | ok |" in report and "| cmp_nn | ok |" in report
    for png in ("pr_all.png", "matches_cmp_seqslam.png", "matches_cmp_nn.png"):
        assert (out / png).stat().st_size > 1000 and png in report
    rows = {row["method"]: row for row in json.loads((out / "results.json").read_text())["runs"]}
    # the table reports exactly what each run's own metrics.json says
    for row in rows.values():
        metrics = json.loads((out / row["run"] / "metrics.json").read_text())
        assert row["recall_at_100p"] == metrics["recall_at_100p"]
        assert row["n_searches"] == metrics["n_searches"]
    assert rows["cmp_seqslam"]["n_searches"] == 40 - 6  # ds/2 queries at each end get no answer
    # a second call resumes: nothing is run again
    code, _, _ = cli("compare", *_recipes(tmp_path), "-o", out, "--workers", "1", "-q")
    assert code == 0


def test_compare_refuses_two_recipes_with_one_name(cli, tmp_path: Path) -> None:
    first = _recipes(tmp_path)[0]
    code, _, stderr = cli("compare", first, first, "-o", tmp_path / "x", "-q")
    assert code == 2 and "two recipes are named 'cmp_seqslam'" in stderr


def test_an_override_that_is_not_yaml_is_a_user_error(cli, tmp_path: Path) -> None:
    code, _, stderr = cli("compare", "demo", "--set", "k=[oops", "-o", tmp_path / "x", "-q")
    assert code == 2 and "--set 'k=[oops': value is not valid YAML" in stderr and "Traceback" not in stderr


def test_compare_writes_nothing_into_a_folder_another_writer_holds(cli, tmp_path: Path) -> None:
    from slamfront.outputs import folder_lock

    out = tmp_path / "cmp"
    with folder_lock(out, "run"):  # a run (or another compare) is writing there
        code, _, stderr = cli("compare", *_recipes(tmp_path), "-o", out, "--workers", "1", "-q")
    assert code == 2 and "Traceback" not in stderr and str(out) in stderr
    # not even the comparison's sweep file: the holder's files are its own
    assert not (out / "compare.yaml").exists() and not (out / "runs").exists()
