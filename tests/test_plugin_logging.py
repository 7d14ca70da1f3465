"""Plugins log with Python's logging: records land in the run's /log, warnings on the terminal."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from slamfront.mcaplog.reader import read_messages
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.registry import PluginRegistry
from slamfront.runtime import run_pipeline
from tests.helpers import small_synthetic_recipe

CHATTY = '''
"""A descriptor that talks: every frame at info, frame 3 at warning, frame 4 from a thread."""
import logging
import threading

import slamfront
from slamfront_plugins.descriptors.downsampled import DownsampledImage

logger = logging.getLogger(__name__)


class Chatty(DownsampledImage):
    """Thumbnails, saying what it sees."""

    name = "chatty"

    def process(self, inputs):
        logger.info("frame %d seen", inputs.frame.index)
        if inputs.frame.index == 3:
            logger.warning("frame 3 looks odd")
        if inputs.frame.index == 4:
            worker = threading.Thread(target=logger.info, args=("from a worker thread",))
            worker.start()
            worker.join()
        return super().process(inputs)


@slamfront.hookimpl
def slamfront_descriptors():
    return [Chatty]
'''


@pytest.fixture
def chatty(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """An importable plugin module in the working directory; returns its name."""
    name = f"chatty_{tmp_path.name}"  # a fresh module per test (sys.modules keeps imports)
    (tmp_path / f"{name}.py").write_text(CHATTY)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def _recipe(module: str, frames: int = 8) -> dict:
    recipe = small_synthetic_recipe(frames_per_traversal=frames)
    recipe["plugin_modules"] = [module]
    recipe["descriptor"]["plugin"] = "chatty"
    return recipe


def _log_records(path: Path) -> list:
    return list(read_messages(path, ["/log"]))


def test_records_go_to_the_log_and_warnings_to_the_terminal(cli, write_recipe, chatty: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, _, err = cli("run", write_recipe(_recipe(chatty)), "-o", out, "-q")
    assert code == 0, err
    # the terminal: the warning, once, naming its logger; no info lines
    assert err.strip().splitlines() == [f"slamfront: warning: {chatty}: frame 3 looks odd"]
    logged = _log_records(out / "run.mcap")
    mine = [m for m in logged if m.decoded.name == chatty]
    assert [m.decoded.message for m in mine[:3]] == ["frame 0 seen", "frame 1 seen", "frame 2 seen"]
    assert len([m for m in mine if m.decoded.message.endswith(" seen")]) == 16  # 2 traversals x 8 frames
    warning = next(m for m in mine if m.decoded.message == "frame 3 looks odd")
    assert warning.decoded.level == 3  # foxglove.Log WARNING
    assert warning.decoded.file == f"{chatty}.py" and warning.decoded.line > 0
    frames = {m.decoded.frame: m.log_time_ns for m in read_messages(out / "run.mcap", ["/frames"])}
    assert warning.log_time_ns == frames[3]  # stamped with the frame being processed
    assert any(m.decoded.message == "from a worker thread" and m.log_time_ns == frames[4] for m in mine)
    assert logged[-1].decoded.message.startswith("run completed")  # the run's own last line stays last


def test_log_level_keeps_only_records_at_or_above_it(cli, write_recipe, chatty: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, _, err = cli("run", write_recipe(_recipe(chatty)), "-o", out, "-q", "--set", "log.level=warning")
    assert code == 0, err
    mine = [m.decoded.message for m in _log_records(out / "run.mcap") if m.decoded.name == chatty]
    assert mine == ["frame 3 looks odd"]


def test_logger_levels_are_restored_after_a_run(chatty: str, tmp_path: Path) -> None:
    before = {name: logging.getLogger(name).level for name in (chatty, "slamfront", "slamfront_plugins")}
    recipe = parse_recipe(_recipe(chatty), "r.yaml")
    run_pipeline(build_pipeline(recipe, "r.yaml", PluginRegistry()), "r.yaml", tmp_path / "out", progress=False)
    after = {name: logging.getLogger(name).level for name in before}
    assert after == before
    assert not any(type(h).__name__ == "_Buffer" for name in before for h in logging.getLogger(name).handlers)


def test_records_do_not_break_replay_or_diff(cli, write_recipe, chatty: str, tmp_path: Path) -> None:
    out, again = tmp_path / "out", tmp_path / "again"
    assert cli("run", write_recipe(_recipe(chatty)), "-o", out, "-q")[0] == 0
    # the log's recipe imports a local module: replay refuses it unless the log is trusted
    assert cli("replay", out, "-o", again, "-q")[0] == 2
    assert cli("replay", out, "-o", again, "-q", "--trust-log")[0] == 0
    code, stdout, _ = cli("diff", out, again)
    assert code == 0, stdout
    # the replay read the descriptor's outputs from the log instead of running it: none of its records
    assert not any(m.decoded.name == chatty for m in _log_records(again / "run.mcap"))


def test_a_built_in_plugin_logs_through_the_same_path(tmp_path: Path) -> None:
    recipe = parse_recipe(small_synthetic_recipe(frames_per_traversal=4), "r.yaml")
    run_pipeline(build_pipeline(recipe, "r.yaml"), "r.yaml", tmp_path, progress=False)
    names = {m.decoded.name for m in _log_records(tmp_path / "run.mcap")}
    assert "slamfront_plugins.sources.synthetic" in names
