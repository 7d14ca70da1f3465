"""The demo (`make run`): the whole front end on one synthetic stream, here on a short
street so it runs in seconds; the full demo's numbers come from benchmarks/bench_demo.py."""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from slamfront.cli import main
from slamfront.mcaplog.reader import summarize
from slamfront.recipe import load_recipe
from tests.helpers import layout_problems

REPO = Path(__file__).resolve().parents[1]
SMALL = [  # a shorter street at the demo's 1.5 m per frame and image size
    "--set", "source.params.frames_per_traversal=80", "--set", "source.params.route_length_m=120",
    "--set", "loop_detector.params.exclude_recent_places=5",
    "--set", "place_map.params.calibration_frames=80",  # nu from the first lap, as the demo's 200
    "--set", "loop_detector.params.accept_calibration_frames=80",  # and the operating point
]


@pytest.fixture(scope="module")
def demo_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """The demo run twice into one folder, as `make run` twice does: (folder, each run's stdout)."""
    out = tmp_path_factory.mktemp("demo") / "demo"
    outputs = []
    for _ in range(2):
        stream = io.StringIO()
        with contextlib.redirect_stdout(stream):
            assert main(["run", "demo", "-o", str(out), "-q", *SMALL]) == 0
        outputs.append(stream.getvalue())
    return out, outputs


def test_make_run_runs_the_demo_recipe() -> None:
    makefile = (REPO / "Makefile").read_text()
    assert re.search(r"^run: setup\n\t\$\(BIN\)/slamfront run demo\b", makefile, re.MULTILINE)
    recipe, _ = load_recipe("demo")
    assert recipe.loop_detector.plugin == "hierarchical_sequence" and recipe.backend.plugin == "gtsam_pose_graph"
    odometry = recipe.backend.params["odometry"]
    assert odometry == "pnp"  # estimated from the images, not ground truth plus noise
    assert load_recipe("paired_demo")[0].loop_detector.plugin == "nearest_neighbour"  # the old demo keeps a name


def test_the_demo_prints_ate_before_and_after_and_the_report_page_twice(demo_runs: tuple[Path, list[str]]) -> None:
    out, outputs = demo_runs
    metrics = json.loads((out / "metrics.json").read_text())
    for stdout in outputs:  # the second run into the same folder works as the first
        assert f"report:  {out / 'report.html'}" in stdout
        assert f"log:     {out / 'run.mcap'}" in stdout
        match = re.search(r"ATE before -> after optimisation: ([\d.]+) m -> ([\d.]+) m", stdout)
        assert match, stdout
    assert match[1] == f"{metrics['ate_rmse_before_m']:.3g}" and match[2] == f"{metrics['ate_rmse_after_m']:.3g}"
    first, second = ([line for line in o.splitlines() if "ATE" in line or "drift" in line] for o in outputs)
    assert first == second and len(first) == 2  # the same run again: the same trajectory


def test_the_demo_verifies_closures_and_optimises_image_odometry(demo_runs: tuple[Path, list[str]]) -> None:
    out, _ = demo_runs
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_loop_constraints_added"] >= 10
    assert metrics["n_loop_constraints_added_false"] == 0 and metrics["precision_verified"] == 1.0
    assert metrics["ate_rmse_after_m"] < 0.5 * metrics["ate_rmse_before_m"]
    assert metrics["drift_after_m"] < metrics["drift_before_m"]
    assert metrics["n_odometry_fallbacks"] < 0.15 * metrics["n_frames"]  # PnP placed most frames
    report = (out / "report.md").read_text()
    for figure in ("trajectory.png", "pr.png", "matches.png", "backend.png"):
        assert (out / figure).is_file() and f"]({figure})" in report
    assert "`slamfront layout slamfront-layout.json`" in report  # the report names the layout to open


def test_the_demo_log_opens_with_the_shipped_layout(demo_runs: tuple[Path, list[str]]) -> None:
    out, _ = demo_runs
    layout = json.loads((REPO / "foxglove" / "slamfront-layout.json").read_text())
    assert layout_problems(layout, out / "run.mcap") == []  # every tab: loop closure and back end


def test_the_demo_log_validates_replays_and_compares_equal_as_a_user_runs_it(
    demo_runs: tuple[Path, list[str]], tmp_path: Path
) -> None:
    """`slamfront inspect LOG --validate`, `slamfront replay LOG -o X` and `slamfront diff LOG X`,
    each in a fresh process that knows the message types only from the installed plugins."""
    out, _ = demo_runs
    replayed = tmp_path / "replayed"
    for args in (["inspect", out, "--validate"], ["replay", out, "-o", replayed, "-q"], ["diff", out, replayed]):
        done = subprocess.run([sys.executable, "-m", "slamfront", *map(str, args)], capture_output=True, text=True,
                              timeout=600)
        assert done.returncode == 0, f"slamfront {args[0]}: {done.stdout[-3000:]}{done.stderr[-3000:]}"
    assert "identical:" in done.stdout
    replay = summarize(replayed / "run.mcap").metadata["replay"]
    assert replay["from"] == "descriptor" and replay["rerun_stages"] == "descriptor,place_map,loop_detector,backend"
