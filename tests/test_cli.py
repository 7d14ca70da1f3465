"""The CLI: the happy paths and every user error (exit 2, one line, no traceback)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront.mcaplog.reader import read_messages, summarize
from tests.helpers import small_synthetic_recipe


def _one_line_error(code: int, err: str) -> str:
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("slamfront: error: ")
    return lines[0]


def test_help_everywhere(cli) -> None:
    for command in ([], ["run"], ["replay"], ["plugins"], ["inspect"], ["diff"], ["recover"], ["recipes"]):
        with pytest.raises(SystemExit) as exit_info:
            cli(*command, "--help")
        assert exit_info.value.code == 0


def test_run_inspect_json(cli, write_recipe, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, stdout, _ = cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q")
    assert code == 0 and "report:" in stdout
    code, stdout, _ = cli("inspect", out / "run.mcap", "--json")
    summary = json.loads(stdout)
    topics = {t["topic"]: t for t in summary["topics"]}
    assert topics["/loop_detector/loop_result"]["count"] == 40
    assert summary["complete"] and summary["n_messages"] > 0 and summary["duration_s"] > 0


def test_recipes_lists_shipped_ones(cli) -> None:
    code, stdout, _ = cli("recipes")
    listed = {line.split()[0] for line in stdout.splitlines() if line.strip()}
    assert code == 0 and "demo" in listed and "paired_demo" in listed


def test_missing_recipe_file(cli, tmp_path: Path) -> None:
    line = _one_line_error(*cli("run", tmp_path / "nope.yaml")[::2])
    assert "nope.yaml: no such recipe file" in line


def test_unknown_plugin_suggests(cli, write_recipe) -> None:
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "--set", "descriptor.plugin=downsampeld")
    line = _one_line_error(code, err)
    assert "descriptor.plugin: unknown descriptor plugin 'downsampeld'; did you mean 'downsampled'?" in line


def test_invalid_param(cli, write_recipe) -> None:
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "--set", "source.params.image_width=abc")
    line = _one_line_error(code, err)
    assert "recipe.yaml: source.params.image_width:" in line and "'abc'" in line


def _folder_with_bad_image(tmp_path: Path, bad: bytes) -> Path:
    folder = tmp_path / "images"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(6):
        cv2.imwrite(str(folder / f"{i:03d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    (folder / "003.png").write_bytes(bad)
    return folder


@pytest.mark.parametrize("bad", [b"not a png at all", b""], ids=["corrupt", "zero-size"])
def test_unreadable_image_mid_run_keeps_the_log(cli, write_recipe, tmp_path: Path, bad: bytes) -> None:
    folder = _folder_with_bad_image(tmp_path, bad)
    recipe = small_synthetic_recipe()
    recipe["source"] = {"plugin": "image_folder", "params": {"folder": str(folder)}}
    recipe["loop_detector"]["params"] = {"exclude_recent": 1}
    out = tmp_path / "out"
    code, _, err = cli("run", write_recipe(recipe), "-o", out, "-q")
    line = _one_line_error(code, err)
    assert "003.png" in line
    summary = summarize(out / "run.mcap")
    assert summary.complete  # finalised although the run stopped
    assert summary.topic("/frames").count == 3
    last = [m.decoded for m in read_messages(out / "run.mcap", ["/log"])][-1]
    assert "bad input after 3 frames" in last.message
    assert not (out / "metrics.json").exists()


def test_truncated_log(cli, write_recipe, tmp_path: Path) -> None:
    out = tmp_path / "out"
    # small chunks, so a cut two thirds in leaves complete chunks before it
    cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q", "--set", "log.chunk_size=8192")
    data = (out / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    code, stdout, err = cli("inspect", cut)
    line = _one_line_error(code, err)
    assert "cut.mcap" in line and "truncated" in line
    assert "INCOMPLETE" in stdout and "/frames" in stdout


def test_not_an_mcap_file(cli, tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_text("hello")
    line = _one_line_error(*cli("inspect", path)[::2])
    assert "x.mcap: not an MCAP file" in line


def test_missing_log(cli, tmp_path: Path) -> None:
    line = _one_line_error(*cli("inspect", tmp_path / "none.mcap")[::2])
    assert "none.mcap: no such log file" in line


def test_building_the_command_line_imports_no_heavy_library() -> None:
    # `slamfront --help` and every sub-command's parser stay cheap: the heavy modules are
    # imported by the command that runs, not by the parser (nothing is timed here)
    import subprocess
    import sys

    heavy = ("cv2", "numpy", "scipy", "gtsam", "numba", "matplotlib", "pydantic", "mcap", "open3d")
    code = (
        "import sys; from slamfront.cli import build_parser; build_parser(); "
        f"print(','.join(m for m in {heavy!r} if m in sys.modules))"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == ""


def test_eval_traj_lists_every_trajectory_format() -> None:
    from slamfront.cli.eval_cmd import FORMATS
    from slamfront.formats.poses import TRAJECTORY_READERS

    assert FORMATS == tuple(sorted(TRAJECTORY_READERS))


def test_every_sub_command_is_built_by_the_module_the_table_names() -> None:
    # `slamfront X` builds only the parser of X's module (COMMANDS): the table must say which
    import argparse

    from slamfront.cli import COMMANDS, build_parser

    full = build_parser()
    (subparsers,) = [a for a in full._actions if isinstance(a, argparse._SubParsersAction)]
    assert list(subparsers.choices) == list(COMMANDS)
    for command in COMMANDS:
        (alone,) = [a for a in build_parser([command])._actions if isinstance(a, argparse._SubParsersAction)]
        assert command in alone.choices and set(alone.choices) <= set(COMMANDS)
