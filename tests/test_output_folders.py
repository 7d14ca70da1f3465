"""An output folder is the run's, and only what the run wrote there is ever replaced.

What an attacker who can write into a shared or unpacked folder, or an unlucky user,
could make a run do to files that are not its own: links planted in the folder, a rerun
after a killed run, a crafted ``.slamfront-run`` manifest, two runs into one folder.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront.errors import SlamfrontError
from slamfront.mcaplog.reader import read_messages
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.outputs import LOCK_FILE, MANIFEST, claim_run_folder, folder_lock
from tests.test_hostile_inputs import BASE_RECIPE, SINGLE_THREADED, assert_one_line_error


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def recipe(tmp_path: Path) -> Path:
    path = tmp_path / "hostile.yaml"
    path.write_text(yaml.safe_dump(BASE_RECIPE))
    return path


def _users_files(folder: Path) -> dict[Path, str]:
    folder.mkdir(parents=True, exist_ok=True)
    files = {folder / "thesis.tex": "\\chapter{mine}", folder / "data.csv": "1,2\n", folder / "notes.txt": "mine"}
    for path, text in files.items():
        path.write_text(text)
    return {path: _digest(path) for path in files}


def test_links_planted_in_the_folder_are_never_written_through(tmp_path: Path, recipe: Path, cli) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    for name in ("pr.png", "run.mcap", "report.md", "metrics.json.tmp"):
        (elsewhere / name).write_text(f"the user's {name}")
        (out / name).symlink_to(elsewhere / name)
    (out / "report.html").symlink_to(elsewhere / "created_through_a_dangling_link.html")
    before = {path: _digest(path) for path in elsewhere.iterdir()}
    for command in (["run", recipe, "-o", out, "-q"], ["replay", _a_log(tmp_path, recipe, cli), "-o", out, "-q"]):
        code, _, err = cli(*command)
        assert_one_line_error(code, err, "symbolic link", str(out / "metrics.json.tmp"), "remove it")
    assert {path: _digest(path) for path in elsewhere.iterdir()} == before
    assert not (elsewhere / "created_through_a_dangling_link.html").exists()


def test_a_link_to_a_folder_is_left_alone_and_the_run_writes_beside_it(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "data").mkdir()
    (out / "data").symlink_to(tmp_path / "data")  # a link to a folder is never opened for writing
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert code == 0, err
    assert (out / "data").is_symlink() and list((tmp_path / "data").iterdir()) == []


def test_outputs_are_written_without_following_a_link_that_appears_mid_run(tmp_path: Path) -> None:
    from slamfront.outputs import open_output, write_atomically

    target = tmp_path / "target.txt"
    target.write_text("the user's")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.txt").symlink_to(target)
    with pytest.raises(SlamfrontError, match="symbolic link"):
        open_output(tmp_path / "out" / "a.txt")
    os.link(target, tmp_path / "out" / "b.txt")
    with pytest.raises(SlamfrontError, match="hard link"):
        open_output(tmp_path / "out" / "b.txt")
    write_atomically(tmp_path / "out" / "a.txt", b"new")  # replaces the link itself
    assert target.read_text() == "the user's" and (tmp_path / "out" / "a.txt").read_bytes() == b"new"


def _a_log(tmp_path: Path, recipe: Path, cli) -> Path:
    log_dir = tmp_path / "a_log"
    if not (log_dir / "run.mcap").exists():
        code, _, err = cli("run", recipe, "-o", log_dir, "-q")
        assert code == 0, err
    return log_dir / "run.mcap"


def _slow_run(out: Path) -> subprocess.Popen[bytes]:
    """A long run in another process, returned once its log has been synced (frames on disk)."""
    env = {**os.environ, **SINGLE_THREADED}
    slow = {**BASE_RECIPE, "source": {"plugin": "synthetic", "params": {
        "frames_per_traversal": 400, "route_length_m": 400, "image_width": 32, "image_height": 24}},
            "log": {"chunk_size": 2048, "sync_seconds": 0.05}}
    path = out.parent / "slow.yaml"
    path.write_text(yaml.safe_dump(slow))
    process = subprocess.Popen([sys.executable, "-m", "slamfront", "run", path, "-o", out, "-q"], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    while '"run.mcap"' not in _text(out / MANIFEST) or "prefix" not in _text(out / MANIFEST):
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            raise AssertionError(process.communicate()[1].decode())
        time.sleep(0.02)
    return process


def _killed_run(out: Path) -> None:
    """A run SIGKILLed once its log has been synced (frames on disk, the run unfinished)."""
    process = _slow_run(out)
    process.kill()
    process.communicate()
    assert json.loads((out / MANIFEST).read_text())["complete"] is False


def _text(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def test_a_rerun_after_a_killed_run_keeps_the_files_added_since(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    _killed_run(out)
    mine = _users_files(out)  # added after the crash: the killed run's manifest never saw them
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert code == 0, err
    assert "held a previous run" in err  # the killed run's log, vouched for by the hash of what it had synced
    assert {path: _digest(path) for path in mine} == mine
    assert [m.decoded.message for m in read_messages(out / "run.mcap", ["/log"])][-1].startswith("run completed")


def test_a_run_stopped_before_its_first_sync_can_be_rerun(tmp_path: Path) -> None:
    # A campaign worker SIGTERMed beside a crashing one can die between creating its log and
    # the first fsync; the log's inode is on record from its creation, so its rerun goes ahead.
    out = tmp_path / "out"
    folder = claim_run_folder(out)
    log = RunLogWriter(out / "run.mcap", on_sync=folder.log_synced)
    log._stream.write(b"\x89MCAP0\r\n" * 2000)  # bytes on disk, never synced
    log._stream.flush()
    folder.lock.release()  # the process is gone: no close, no record of the log's content
    mine = _users_files(out)
    again = claim_run_folder(out)
    again.close()
    assert not (out / "run.mcap").exists()
    assert {path: _digest(path) for path in mine} == mine
    # stopped inside close(): the run records itself ended, then the log's buffer reaches the disk at exit
    stopped = claim_run_folder(out)
    log = RunLogWriter(out / "run.mcap", on_sync=stopped.log_synced)
    log.sync()
    log._stream.write(b"\0" * 100)
    stopped.close()
    log._stream.flush()
    again = claim_run_folder(out)
    again.close()
    assert not (out / "run.mcap").exists()
    # a file of that name on another inode (the user's own, put there since) is never taken for that log
    killed = claim_run_folder(out)
    RunLogWriter(out / "run.mcap", on_sync=killed.log_synced)
    killed.lock.release()
    (out / "run.mcap").unlink()
    (out / "run.mcap").write_bytes(b"mine")
    with pytest.raises(SlamfrontError, match="vouches"):
        claim_run_folder(out)
    assert (out / "run.mcap").read_bytes() == b"mine"


def test_a_crafted_manifest_deletes_nothing_of_the_users(tmp_path: Path, recipe: Path, cli) -> None:
    names = ["thesis.tex", "data.csv", "notes.txt"]
    empty = hashlib.sha256(b"").hexdigest()
    crafted: list[Any] = [
        {"complete": False, "files": [], "before": []},  # the manifest of an older slamfront
        {"complete": True, "files": names, "before": []},
        {"format": 2, "complete": True, "files": {n: {"size": 5, "sha256": "0" * 64} for n in names}},
        {"format": 2, "complete": False, "files": {n: {"size": 0, "sha256": empty, "prefix": True} for n in names}},
        {"format": 2, "complete": True, "files": {"../" + n: {"size": 1, "sha256": empty} for n in names}},
        [1, 2, 3],
    ]
    for index, manifest in enumerate(crafted):
        out = tmp_path / f"out{index}"
        mine = _users_files(out)
        (out / MANIFEST).write_text(json.dumps(manifest))
        code, _, err = cli("run", recipe, "-o", out, "-q", "--max-frames", "3")
        assert code == 0, err
        assert {path: _digest(path) for path in mine} == mine, manifest


def test_a_file_no_manifest_vouches_for_is_never_replaced(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert code == 0, err
    (out / "report.md").write_text("my edits to the report")  # changed since the run wrote it
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert_one_line_error(code, err, str(out / "report.md"), "move it")
    assert (out / "report.md").read_text() == "my edits to the report"
    (out / "report.md").unlink()
    (out / MANIFEST).unlink()  # a folder without a manifest (an older slamfront's): its log is not vouched for
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert_one_line_error(code, err, str(out / "run.mcap"))


def test_one_run_at_a_time_per_folder(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    log = _a_log(tmp_path, recipe, cli)
    with folder_lock(out, "run"):
        for command in (["run", recipe, "-o", out, "-q"], ["replay", log, "-o", out, "-q"]):
            code, _, err = cli(*command)
            assert_one_line_error(code, err, str(out), f"process {os.getpid()}")
    assert not (out / "run.mcap").exists()


def test_a_second_run_into_a_folder_in_use_refuses_and_removes_nothing(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    first = _slow_run(out)
    try:
        size = (out / "run.mcap").stat().st_size
        code, _, err = cli("run", recipe, "-o", out, "-q")
        assert_one_line_error(code, err, str(out), "is using this folder", f"process {first.pid}")
        assert first.poll() is None and (out / "run.mcap").stat().st_size >= size  # the first run's log is intact
    finally:
        first.kill()
        first.communicate()


def test_a_stale_lock_of_a_dead_process_is_taken_over(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / LOCK_FILE).write_text(f"run process {dead.pid}\n")  # a lock file left by a process that died
    code, _, err = cli("run", recipe, "-o", out, "-q", "--max-frames", "2")
    assert code == 0, err


def test_the_lock_and_the_manifest_are_not_outputs(tmp_path: Path) -> None:
    folder = claim_run_folder(tmp_path / "out")
    try:
        (tmp_path / "out" / "run.mcap").write_bytes(b"x")
        folder.record(complete=True)
    finally:
        folder.close()
    files = json.loads((tmp_path / "out" / MANIFEST).read_text())["files"]
    assert sorted(files) == ["run.mcap"] and files["run.mcap"]["size"] == 1


def test_the_manifest_vouches_for_every_file_the_run_wrote_as_it_is(tmp_path: Path, recipe: Path, cli) -> None:
    out = tmp_path / "out"
    (tmp_path / "out").mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = cli("run", recipe, "-o", out, "-q")
    assert code == 0, err
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["complete"] is True
    on_disk = {p.name for p in out.iterdir()} - {MANIFEST, LOCK_FILE, "notes.txt"}
    assert set(manifest["files"]) == on_disk and {"run.mcap", "metrics.json", "report.md"} <= on_disk
    for name, entry in manifest["files"].items():  # the log's hash is its writer's, never read back
        assert entry == {"size": (out / name).stat().st_size, "sha256": _digest(out / name)}, name


def test_a_run_killed_just_after_writing_an_output_leaves_it_vouched_for(tmp_path: Path) -> None:
    """A kill between the rename of metrics.json and the next manifest write (a worker of a
    broken process pool is killed at any moment) must not make the rerun refuse the folder."""
    from slamfront.report.metrics_file import write_json_atomically

    out = tmp_path / "out"
    folder = claim_run_folder(out)
    write_json_atomically(out / "metrics.json", {"n_frames": 3}, folder.announce)
    folder.lock.release()  # killed here: no record after the rename, no close
    assert json.loads((out / MANIFEST).read_text())["complete"] is False
    again = claim_run_folder(out)  # vouched for by the announcement: removed, not refused
    try:
        assert again.replaced == ["metrics.json"] and not (out / "metrics.json").exists()
    finally:
        again.close()


def test_every_writer_replaces_a_planted_link_instead_of_writing_through_it(tmp_path: Path) -> None:
    """The writers outside run folders (models, pose graphs) rename onto
    their path too: a link planted there, or at the temporary name beside it, is never followed."""
    import numpy as np

    from slamfront.formats.ply import write_ply
    from slamfront.posegraph.io import read_graph, write_g2o

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    source = tmp_path / "line.g2o"
    source.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    graph = read_graph(source).parsed.graph
    for name in ("model.ply", "graph.g2o", "model.ply.tmp", "graph.g2o.tmp"):
        (elsewhere / name).write_text("the user's file\n")
        (out / name).symlink_to(elsewhere / name)
    write_ply(out / "model.ply", np.zeros((4, 3), np.float32))
    write_g2o(out / "graph.g2o", graph, graph.poses)
    for name in ("model.ply", "graph.g2o", "model.ply.tmp", "graph.g2o.tmp"):
        assert (elsewhere / name).read_text() == "the user's file\n"
    assert not (out / "model.ply").is_symlink() and (out / "graph.g2o").read_text().startswith("VERTEX_SE2 0")


def test_a_campaign_worker_cannot_send_back_a_file_outside_its_run_folder(tmp_path: Path) -> None:
    from slamfront.campaign.store import CampaignStore

    store = CampaignStore.__new__(CampaignStore)
    folder = tmp_path / "campaign" / "run-0"
    folder.mkdir(parents=True)
    for name in ("../../escaped.txt", "/tmp/escaped.txt", ""):
        with pytest.raises(SlamfrontError, match="outside its run folder"):
            store.save_files(folder, {name: b"x"})
    store.save_files(folder, {"plots/pr.png": b"png"})
    assert (folder / "plots" / "pr.png").read_bytes() == b"png"
    assert not (tmp_path / "escaped.txt").exists()


def test_optimize_refuses_a_folder_another_command_is_writing(tmp_path: Path, cli) -> None:
    """`optimize -o DIR` takes the folder's lock too: a second writer would leave a mix of both."""
    graph = tmp_path / "square.g2o"
    graph.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 1 1 0\nVERTEX_SE2 3 0 1 0\n"
        + "".join(f"EDGE_SE2 {i} {i + 1} 1 0 1.5708 1 0 0 1 0 1\n" for i in range(3))
        + "EDGE_SE2 3 0 1 0 1.5708 1 0 0 1 0 1\n"
    )
    out = tmp_path / "out"
    with folder_lock(out, "run"):
        code, _, err = cli("optimize", str(graph), "-o", str(out), "--no-plots")
        assert_one_line_error(code, err, str(out), "another run", "is using this folder")
    code, _, err = cli("optimize", str(graph), "-o", str(out), "--no-plots")
    assert code == 0, err
    assert (out / "optimized.g2o").is_file()
