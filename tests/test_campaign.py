"""Campaigns end to end: the local pool and Ray give the same table, an interrupted
campaign resumes, failing and crashing runs are recorded while the rest complete."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from slamfront.campaign import RayBackend, run_campaign, start_ray
from slamfront.campaign.store import RECORD_FILE
from slamfront.evaluation.loops import read_pr_curve
from slamfront.mcaplog.reader import summarize
from tests.helpers import small_synthetic_recipe
from tests.test_sweep_file import write_sweep

SIX_RUNS = {
    "grid": {"loop_detector.params.uniqueness_window": [2, 10, 30]},
    "repetitions": 2,
    "repetition_seed": "source.params.seed",
    "metrics": ["recall_at_100p", "auc_pr", "recall_at_1", "n_queries", "timing.descriptor.median_ms"],
}


def quiet_recipe(**source_params: Any) -> dict[str, Any]:
    recipe = small_synthetic_recipe(**source_params)
    recipe["log"] = {"images": False}
    return recipe


@pytest.fixture(scope="session")
def ray_local() -> Iterator[None]:
    """One in-process Ray instance with 2 CPUs for the whole session, started the way
    ``slamfront sweep --ray local`` starts it (the CLI then reuses it)."""
    import ray

    start_ray("local", 2)
    yield
    ray.shutdown()


def read_rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open() as handle:
        return list(csv.DictReader(handle))


def deterministic(out: Path) -> list[dict[str, str]]:
    """The results table without its wall-clock columns (results.json lists them)."""
    timing = set(json.loads((out / "results.json").read_text())["timing_columns"])
    return [{k: v for k, v in row.items() if k not in timing} for row in read_rows(out)]


def test_pool_and_ray_give_identical_tables(cli, tmp_path: Path, ray_local: None) -> None:
    sweep = write_sweep(tmp_path, SIX_RUNS, quiet_recipe())
    tables = {}
    for name, options in {
        "workers1": ["--workers", "1"], "workers2": ["--workers", "2"], "ray": ["--ray", "local", "--workers", "2"],
    }.items():
        code, stdout, stderr = cli("sweep", sweep, "-o", tmp_path / name, "-q", *options)
        assert code == 0, stderr
        assert "6 (6 ran now, 0 already finished): 6 ok, 0 failed" in stdout
        tables[name] = deterministic(tmp_path / name)
    assert tables["workers1"] == tables["workers2"] == tables["ray"]
    rows = tables["workers1"]
    assert [row["status"] for row in rows] == ["ok"] * 6
    assert [row["loop_detector.params.uniqueness_window"] for row in rows] == ["2", "2", "10", "10", "30", "30"]
    assert [row["repetition"] for row in rows] == ["0", "1"] * 3
    assert len({row["recall_at_100p"] + row["auc_pr"] for row in rows}) > 1, "the runs should differ"
    assert all(row["n_queries"] == "40" for row in rows)
    timing = read_rows(tmp_path / "workers1")
    assert all(float(row["timing.descriptor.median_ms"]) > 0 and float(row["wall_seconds"]) > 0 for row in timing)

    out = tmp_path / "workers2"
    run_dir = out / read_rows(out)[0]["run"]
    assert summarize(run_dir / "run.mcap").complete
    metrics = json.loads((run_dir / "metrics.json").read_text())
    _, precision, recall = read_pr_curve(run_dir / "pr_curve.csv")
    assert float(recall[precision >= 1.0].max(initial=0.0)) == pytest.approx(metrics["recall_at_100p"])
    for figure in ("vs_uniqueness_window.png", "pr.png"):
        assert (out / figure).stat().st_size > 5000
    report = (out / "report.md").read_text()
    assert "6 runs: 6 ok" in report and "![pr.png](pr.png)" in report


def test_failing_run_is_recorded_and_the_rest_complete(cli, tmp_path: Path, shared_data: Path) -> None:
    sweep = write_sweep(tmp_path, {
        "cases": [
            {},
            {"source": {"plugin": "image_folder", "params": {"folder": "images/loop10"}}},
            {"source": {"plugin": "image_folder", "params": {"folder": "images/no_such_folder"}}},
        ],
        "metrics": ["n_frames", "recall_at_100p"],
    }, quiet_recipe())
    out = tmp_path / "out"
    code, stdout, stderr = cli("sweep", sweep, "-o", out, "--workers", "2", "-q")
    assert code == 1, stderr
    assert "3 (3 ran now, 0 already finished): 2 ok, 1 failed" in stdout
    rows = read_rows(out)
    assert [row["status"] for row in rows] == ["ok", "ok", "failed"]
    assert [row["n_frames"] for row in rows] == ["80", "10", ""]  # the real images: 10 frames
    assert rows[2]["error"] == f"DataError: {shared_data / 'images/no_such_folder'}: no such image folder"
    assert (out / rows[2]["run"] / "error.txt").read_text().strip() == rows[2]["error"]
    assert "## Failed runs" in (out / "report.md").read_text()
    assert "failed: small source=" in stderr


def test_ray_runs_can_send_their_files_back(tmp_path: Path, ray_local: None, shared_data: Path) -> None:
    """Without a shared filesystem, a Ray worker returns the run folder; failures too."""
    sweep = write_sweep(tmp_path, {
        "cases": [{}, {"source": {"plugin": "image_folder", "params": {"folder": "images/no_such_folder"}}}],
    }, quiet_recipe())
    backend = RayBackend("local", workers=2, shared_dir=False)
    result = run_campaign(sweep, tmp_path / "out", backend, progress=False)
    assert [row["status"] for row in result.table.rows] == ["ok", "failed"]
    ok_dir, failed_dir = (result.out_dir / row["run"] for row in result.table.rows)
    assert {"run.mcap", "metrics.json", "report.md", "pr_curve.csv", RECORD_FILE} <= {p.name for p in ok_dir.iterdir()}
    assert summarize(ok_dir / "run.mcap").complete
    assert "no such image folder" in (failed_dir / "error.txt").read_text()


CRASHING_PLUGIN = '''
import os
from slamfront import LoopDetector, PluginConfig, hookimpl
from pydantic import Field


class Crashing(LoopDetector):
    """Ends its process on the first query when told to: a segfault stand-in."""

    name = "crashing"

    class Config(PluginConfig):
        crash: bool = Field(False, description="call os._exit(7) on the first query frame")
        tag: int = Field(0, description="only makes runs differ")
        fail: bool = Field(False, description="raise ValueError on the first query frame")

    def process(self, inputs):
        if self.config.crash and inputs.frame.traversal == "query":
            os._exit(7)
        if self.config.fail and inputs.frame.traversal == "query":
            raise ValueError("told to fail")
        return []


@hookimpl
def slamfront_loop_detectors():
    return [Crashing]
'''


def test_a_crashing_worker_fails_only_its_run(cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "crashing_plugin.py").write_text(CRASHING_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))  # spawned workers get the parent's sys.path
    recipe = quiet_recipe(frames_per_traversal=10)
    recipe["plugin_modules"] = ["crashing_plugin"]
    recipe["loop_detector"] = {"plugin": "crashing", "params": {}}
    # each crashing run starts beside a good one, which must not be blamed
    cases = [(True, 1), (False, 1), (False, 2), (True, 2)]
    sweep = write_sweep(tmp_path, {
        "cases": [{"loop_detector.params.crash": crash, "loop_detector.params.tag": tag} for crash, tag in cases],
        "metrics": ["n_frames"],
    }, recipe)
    code, stdout, stderr = cli("sweep", sweep, "-o", tmp_path / "out", "--workers", "2", "-q")
    assert code == 1, stderr
    rows = read_rows(tmp_path / "out")
    assert "4 (4 ran now, 0 already finished): 2 ok, 2 failed" in stdout, (rows, stderr)
    assert [row["status"] for row in rows] == ["failed", "ok", "ok", "failed"]
    assert [row["n_frames"] for row in rows] == ["", "20", "20", ""]
    assert all("worker process died" in rows[i]["error"] for i in (0, 3))


def test_a_run_failing_mid_way_names_the_stage_and_its_partial_log(
    cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "crashing_plugin.py").write_text(CRASHING_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    recipe = quiet_recipe(frames_per_traversal=10)
    recipe["plugin_modules"] = ["crashing_plugin"]
    recipe["loop_detector"] = {"plugin": "crashing", "params": {"fail": True}}
    sweep = write_sweep(tmp_path, {"cases": [{}], "metrics": ["n_frames"]}, recipe)
    code, _, stderr = cli("sweep", sweep, "-o", tmp_path / "out", "--workers", "1", "-q")
    assert code == 1
    row = read_rows(tmp_path / "out")[0]
    assert row["error"] == "ValueError: told to fail (in the loop_detector plugin 'crashing' at frame 10)"
    log = tmp_path / "out" / row["run"] / "run.mcap"
    assert f"{row['error']} (the log written so far: {log})" in stderr and log.is_file()


def _finished_runs(out: Path) -> dict[Path, int]:
    found = {}
    for record in out.glob(f"runs/*/{RECORD_FILE}"):
        if json.loads(record.read_text())["status"] == "ok":
            found[record.parent] = (record.parent / "metrics.json").stat().st_mtime_ns
    return found


def test_interrupted_campaign_resumes_without_redoing_finished_runs(cli, tmp_path: Path) -> None:
    sweep = write_sweep(tmp_path, SIX_RUNS, quiet_recipe(frames_per_traversal=100))
    out = tmp_path / "out"
    command = [str(Path(sys.executable).parent / "slamfront"), "sweep", str(sweep), "-o", str(out), "--workers", "1", "-q"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while len(_finished_runs(out)) < 2 and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert "interrupted: run the same command again to resume" in stdout
    before = _finished_runs(out)
    statuses = [row["status"] for row in read_rows(out)]
    assert 2 <= statuses.count("ok") == len(before) < 6 and statuses.count("pending") == 6 - len(before)
    # a run stopped midway has a finalised, readable log
    for folder in (out / "runs").iterdir():
        if folder not in before and (folder / "run.mcap").exists():
            assert summarize(folder / "run.mcap").complete

    code, stdout, stderr = cli("sweep", sweep, "-o", out, "--workers", "1", "-q")
    assert code == 0, stderr
    assert f"6 ({6 - len(before)} ran now, {len(before)} already finished): 6 ok" in stdout
    after = _finished_runs(out)
    assert len(after) == 6 and all(after[folder] == mtime for folder, mtime in before.items())
    assert [row["status"] for row in read_rows(out)] == ["ok"] * 6
    # and nothing left to do the third time
    code, stdout, _ = cli("sweep", sweep, "-o", out, "-q")
    assert code == 0 and "(0 ran now, 6 already finished)" in stdout
    assert np.all([_finished_runs(out)[f] == after[f] for f in after])


def test_a_finished_run_made_by_other_code_is_run_again(cli, tmp_path: Path) -> None:
    sweep = write_sweep(tmp_path, {"grid": {"loop_detector.params.uniqueness_window": [2, 10]}},
                        quiet_recipe(frames_per_traversal=40))
    out = tmp_path / "out"
    code, _, stderr = cli("sweep", sweep, "-o", out, "--workers", "1", "-q")
    assert code == 0, stderr
    records = sorted((out / "runs").glob(f"*/{RECORD_FILE}"))
    assert len(records) == 2 and all(len(json.loads(r.read_text())["code"]) == 16 for r in records)
    # as if the first run had been made before a detector changed
    stale = json.loads(records[0].read_text())
    records[0].write_text(json.dumps({**stale, "code": "0" * 16}))
    code, stdout, stderr = cli("sweep", sweep, "-o", out, "--workers", "1", "-q")
    assert code == 0, stderr
    assert "1 finished run was made by other code" in stderr and "running it again" in stderr
    assert "(1 ran now, 1 already finished)" in stdout
    assert json.loads(records[0].read_text())["code"] == json.loads(records[1].read_text())["code"]
