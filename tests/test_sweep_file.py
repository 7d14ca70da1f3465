"""Sweep files and their expansion into runs (no run is executed here)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront.campaign import plan_runs, read_sweep
from slamfront.campaign.plan import format_value
from slamfront.campaign.results import cell, metric_value
from slamfront.campaign.sweepfile import sweeps_dir
from tests.helpers import small_synthetic_recipe
from tests.test_cli import _one_line_error


def write_sweep(folder: Path, sweep: dict[str, Any], recipe: dict[str, Any] | None = None) -> Path:
    """A sweep file beside a small synthetic recipe ``small.yaml`` (the sweep names it by
    default; a key given as None is left out)."""
    (folder / "small.yaml").write_text(yaml.safe_dump(recipe or small_synthetic_recipe()))
    path = folder / "sweep.yaml"
    content = {k: v for k, v in {"name": "test", "recipe": "small.yaml", **sweep}.items() if v is not None}
    path.write_text(yaml.safe_dump(content, sort_keys=False))
    return path


def test_expansion_order_counts_and_precedence(tmp_path: Path) -> None:
    path = write_sweep(tmp_path, {
        "set": {"loop_detector.params.threshold": 0.5, "source.params.seed": 7},
        "variants": {"dusk": {}, "night": {"source.params.query_illumination": "night"}},
        "cases": [{"loop_detector.params.candidates": 3}, {"loop_detector.params.candidates": 5}],
        "grid": {"loop_detector.params.uniqueness_window": [2, 10, 30], "loop_detector.params.threshold": [0.1, 0.2]},
        "repetitions": 2,
        "repetition_seed": "source.params.seed",
    })
    runs = plan_runs(read_sweep(path), path)
    assert len(runs) == 2 * 2 * 3 * 2 * 2
    assert [r.index for r in runs] == list(range(len(runs)))
    first, last = runs[0], runs[-1]
    assert first.labels == {"variant": "dusk"} and last.labels == {"variant": "night"}
    assert first.params == {"loop_detector.params.candidates": 3, "loop_detector.params.uniqueness_window": 2,
                            "loop_detector.params.threshold": 0.1}
    # grid beats the sweep-wide set; the repetition seed beats the sweep-wide seed
    assert first.recipe["loop_detector"]["params"]["threshold"] == 0.1
    assert [r.recipe["source"]["params"]["seed"] for r in runs[:2]] == [0, 1]
    assert last.recipe["source"]["params"]["query_illumination"] == "night"
    assert len({r.key for r in runs}) == len(runs) and len({r.name for r in runs}) == len(runs)
    assert "variant=night" in last.describe() and "uniqueness_window=30" in last.describe()


def test_keys_are_stable_and_follow_the_resolved_recipe(tmp_path: Path) -> None:
    path = write_sweep(tmp_path, {"grid": {"loop_detector.params.uniqueness_window": [2, 10]}})
    keys = [r.key for r in plan_runs(read_sweep(path), path)]
    assert keys == [r.key for r in plan_runs(read_sweep(path), path)]
    # a label is not part of the recipe: renaming it keeps the key; a value change does not
    renamed = write_sweep(tmp_path, {"recipe": None, "recipes": {"other_label": {"recipe": "small.yaml"}},
                                     "grid": {"loop_detector.params.uniqueness_window": [2, 10]}})
    relabelled = plan_runs(read_sweep(renamed), renamed)
    assert [r.key for r in relabelled] == keys and relabelled[0].method == "other_label"
    changed = write_sweep(tmp_path, {"grid": {"loop_detector.params.uniqueness_window": [2, 11]}})
    assert [r.key for r in plan_runs(read_sweep(changed), changed)][1] != keys[1]
    limited = plan_runs(read_sweep(path), path, max_frames=10)
    assert limited[0].key != keys[0] and limited[0].max_frames == 10


def test_methods_with_labels(tmp_path: Path) -> None:
    path = write_sweep(tmp_path, {"recipe": None, "recipes": {
        "nn_exp1": {"recipe": "small.yaml", "labels": {"method": "nn", "experiment": "exp1"}},
        "nn_exp2": {"recipe": "small.yaml", "set": {"source.params.seed": 3},
                    "labels": {"method": "nn", "experiment": "exp2"}},
    }})
    runs = plan_runs(read_sweep(path), path)
    assert [(r.method, r.labels) for r in runs] == [("nn", {"experiment": "exp1"}), ("nn", {"experiment": "exp2"})]
    assert runs[1].recipe["source"]["params"]["seed"] == 3


@pytest.mark.parametrize("value", [1e-9, 0.3, "0.3", "yes", True, None, [1, 2.5], {"a": "b c"}, "night", 10])
def test_override_values_round_trip(value: Any) -> None:
    assert yaml.safe_load(format_value(value)) == value


def test_result_cells_and_dotted_metrics() -> None:
    assert [cell(v) for v in (None, 0.1, 3, True, "x", [1, 2])] == ["", "0.1", "3", "true", "x", "[1, 2]"]
    metrics = {"auc_pr": 0.5, "timing": {"descriptor": {"median_ms": 1.5}}}
    assert metric_value(metrics, "auc_pr") == 0.5
    assert metric_value(metrics, "timing.descriptor.median_ms") == 1.5
    assert metric_value(metrics, "timing.nope") is None


@pytest.mark.parametrize(
    ("sweep", "expected"),
    [
        ({"grid": {"loop_detector.params.threshold": []}}, "grid: loop_detector.params.threshold: a grid axis needs"),
        ({"grid": {"a..b": [1]}}, "grid: 'a..b' is not an override path"),
        ({"recipes": {"x": {"recipe": "small.yaml"}}}, "give either `recipe`"),
        ({"bogus": 1}, "bogus: unknown key; known keys: "),
        ({"repetitions": 0}, "repetitions: Input should be greater than or equal to 1"),
        ({"cases": [{"loop_detector.params.threshold": 0.1}], "grid": {"loop_detector.params.threshold": [0.2]}},
         "loop_detector.params.threshold is both a grid axis and set by a case"),
        ({"recipe": "no_such_recipe"}, "recipe: no such recipe 'no_such_recipe'"),
        ({"grid": {"loop_detector.params.threshold": [0.1, 2.0]}},
         "run 'small threshold=2.0' (", ),
        ({"grid": {"loop_detector.params.acept": [0.1]}}, "loop_detector.params.acept: unknown parameter of the nearest_neighbour loop_detector; did you mean 'accept'?"),
        ({"variants": {"a": {}, "b": {}}}, "resolve to the same recipe"),
    ],
)
def test_bad_sweeps_fail_before_any_run(cli, tmp_path: Path, sweep: dict[str, Any], expected: str) -> None:
    path = write_sweep(tmp_path, sweep)
    out = tmp_path / "out"
    line = _one_line_error(*cli("sweep", path, "-o", out, "-q")[::2])
    assert str(path) in line and expected in line
    assert not out.exists()


def test_bad_sweep_files(cli, tmp_path: Path) -> None:
    line = _one_line_error(*cli("sweep", tmp_path / "nope.yaml")[::2])
    assert "nope.yaml: no such sweep file" in line
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: x\ngrid: [1,\n")
    assert f"{broken}:3: not valid YAML" in _one_line_error(*cli("sweep", broken)[::2])
    broken.write_text("- just a list\n")
    assert "a sweep must be a YAML mapping" in _one_line_error(*cli("sweep", broken)[::2])


def test_invalid_param_names_the_run_and_field(cli, tmp_path: Path) -> None:
    path = write_sweep(tmp_path, {"grid": {"loop_detector.params.accept": [0.1, 2.0]}})
    line = _one_line_error(*cli("sweep", path, "--dry-run")[::2])
    assert "loop_detector.params.accept: accept must be auto or a confidence in [0, 1] (got 2.0)" in line


@pytest.mark.parametrize("path", sorted(sweeps_dir().glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_sweeps_validate(path: Path) -> None:
    sweep = read_sweep(path)
    assert sweep.name == path.stem and sweep.description, f"{path}: needs its file name as name and a description"
    runs = plan_runs(sweep, path)  # every run's recipe and plugin params validated
    assert runs and all(r.recipe for r in runs)


def test_the_synthetic_sweep_runs_today() -> None:
    path = sweeps_dir() / "synthetic_nn.yaml"
    runs = plan_runs(read_sweep(path), path)
    assert len(runs) == 24 and {r.labels["variant"] for r in runs} == {"dusk", "night"}


def test_campaign_figures_from_a_table(tmp_path: Path) -> None:
    """Two methods x two experiments x a 3-value parameter x 2 repetitions, drawn without running."""
    import numpy as np

    from slamfront.campaign import plots
    from slamfront.campaign.results import ResultsTable

    table = ResultsTable(columns=[], label_columns=["experiment"], param_columns=["loop_detector.params.nu"],
                         metric_columns=["recall_at_100p", "ate_rmse_m"], rows=[], repetitions=True)
    curves = {}
    for method in ("hsl", "seqslam"):
        for experiment in ("exp1", "exp2"):
            for nu in (0.5, 0.7, 0.9):
                for repetition in (0, 1):
                    recall = 0.5 * nu + (0.2 if method == "hsl" else 0.0) + 0.01 * repetition
                    curves[len(table.rows)] = (np.linspace(0, recall, 5), np.linspace(1, 0.6, 5))
                    table.rows.append({"status": "ok", "method": method, "experiment": experiment,
                                       "loop_detector.params.nu": nu, "repetition": repetition,
                                       "recall_at_100p": recall, "ate_rmse_m": 1 - recall})
    table.rows.append({"status": "failed", "method": "hsl", "experiment": "exp1", "loop_detector.params.nu": 1.0,
                       "repetition": 0, "recall_at_100p": None, "ate_rmse_m": None})
    figures = [*plots.metric_vs_parameter(table, tmp_path), *plots.methods_side_by_side(table, tmp_path),
               *plots.pr_curves(table, curves, tmp_path)]
    assert sorted(p.name for p in figures) == ["methods.png", "pr_exp1.png", "pr_exp2.png", "vs_nu.png"]
    assert all(p.stat().st_size > 5000 for p in figures)
    assert plots.higher_is_better("recall_at_100p") and not plots.higher_is_better("ate_rmse_m")


def test_the_documented_sweep_example_is_valid(tmp_path: Path) -> None:
    guide = (Path(__file__).resolve().parents[1] / "docs" / "campaigns.md").read_text()
    section = guide.split("## Campaigns", 1)[1]
    example = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "example.yaml"
    path.write_text(example)
    runs = plan_runs(read_sweep(path), path)
    assert len(runs) == 2 * 3 * 2 * 2  # variants x grid x cases(1) x repetitions
    assert runs[1].recipe["source"]["params"]["seed"] == 1


def test_sweep_help(cli) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli("sweep", "--help")
    assert exit_info.value.code == 0


def test_pr_curve_file_round_trips_exactly(tmp_path: Path) -> None:
    import numpy as np

    from slamfront.core.loops import precision_recall
    from slamfront.evaluation.loops import read_pr_curve, write_pr_curve

    rng = np.random.default_rng(3)
    curve = precision_recall(rng.random(50), rng.random(50) > 0.1, rng.random(50) > 0.3, 45)
    thresholds, precision, recall = read_pr_curve(write_pr_curve(curve, tmp_path / "pr_curve.csv"))
    assert np.array_equal(thresholds, curve.thresholds) and np.array_equal(precision, curve.precision)
    assert np.array_equal(recall, curve.recall)
    empty = precision_recall(np.zeros(0), np.zeros(0, bool), np.zeros(0, bool), 0)
    assert [len(a) for a in read_pr_curve(write_pr_curve(empty, tmp_path / "empty.csv"))] == [0, 0, 0]


def test_bad_ray_addresses(cli, tmp_path: Path) -> None:
    path = write_sweep(tmp_path, {})
    line = _one_line_error(*cli("sweep", path, "--ray", "nonsense", "-q")[::2])
    assert "--ray nonsense: expected local, auto, ray://HOST:PORT or HOST:PORT" in line
    # (called directly: a Ray instance this test session started would be reused by the CLI)
    from slamfront.campaign import start_ray
    from slamfront.errors import SlamfrontError

    with pytest.raises(SlamfrontError, match="--ray 127.0.0.1:1: no Ray cluster answers there"):
        start_ray("127.0.0.1:1", 1)
