"""The CLI helps: did-you-mean for every unknown key, plugin switches, warnings, the partial
log's path on every failure, shell completion, help texts and the source's time."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront import DataError
from slamfront.cli import build_parser
from slamfront.mcaplog.reader import read_messages
from slamfront.recipe import apply_overrides
from slamfront.replay import log_recipe
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from tests.helpers import small_synthetic_recipe
from tests.test_cli import _one_line_error


@pytest.mark.parametrize(
    ("where", "override", "expected"),
    [
        ("recipe top level", "loop_detectr.plugin=x", "loop_detectr: unknown key; did you mean 'loop_detector'?"),
        ("stage key", "descriptor.plugn=x", "descriptor.plugn: unknown key; did you mean 'plugin'?"),
        (
            "plugin param",
            "loop_detector.params.acept=0.3",
            "loop_detector.params.acept: unknown parameter of the nearest_neighbour loop_detector; "
            "did you mean 'accept'?",
        ),
        (
            "plugin param typed short",
            "source.params.frames=3",
            "source.params.frames: unknown parameter of the synthetic source; did you mean 'frames_per_traversal'?",
        ),
        ("log option", "log.imagez=false", "log.imagez: unknown key; did you mean 'images'"),
        ("eval option", "eval.plot=false", "eval.plot: unknown key; did you mean 'plots'?"),
    ],
)
def test_every_unknown_key_gets_a_suggestion(cli, write_recipe, where: str, override: str, expected: str) -> None:
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "--set", override, "-q")
    line = _one_line_error(code, err)
    assert expected in line, where
    assert "Extra inputs are not permitted" not in line


def test_unknown_key_written_in_the_recipe_file_gets_a_suggestion(cli, write_recipe) -> None:
    recipe = small_synthetic_recipe()
    recipe["log"] = {"jpeg_qualty": 50}
    line = _one_line_error(*cli("run", write_recipe(recipe), "-q")[::2])
    assert "recipe.yaml: log.jpeg_qualty: unknown key; did you mean 'jpeg_quality'?" in line


def test_unknown_key_with_nothing_close_lists_the_known_ones(cli, write_recipe) -> None:
    line = _one_line_error(*cli("run", write_recipe(small_synthetic_recipe()), "--set", "eval.zzz=1")[::2])
    assert ("eval.zzz: unknown key; known keys: loop_scoring, plots, recall_at_k, retrieval_max_k, tolerances, "
            "unsearched_frames") in line


def test_unknown_sweep_key_gets_a_suggestion(cli, tmp_path: Path) -> None:
    sweep = tmp_path / "s.yaml"
    sweep.write_text(yaml.safe_dump({"name": "s", "recipe": "demo", "grid": {}, "metrix": ["auc_pr"]}))
    line = _one_line_error(*cli("sweep", sweep, "-o", tmp_path / "out")[::2])
    assert "metrix: unknown key; did you mean 'metrics'?" in line


def test_switching_plugin_starts_from_its_own_defaults(cli, write_recipe, tmp_path: Path) -> None:
    # the recipe's downsampled params (width, height) would be unknown to colour_histogram
    out = tmp_path / "out"
    code, _, err = cli(
        "run", write_recipe(small_synthetic_recipe()), "-o", out, "-q", "--max-frames", "3",
        "--set", "descriptor.params.hue_bins=8",  # given before the switch: still applies to the new plugin
        "--set", "descriptor.plugin=colour_histogram",
    )
    assert code == 0, err
    descriptor = log_recipe(out / "run.mcap").descriptor
    assert descriptor is not None and descriptor.plugin == "colour_histogram"
    assert descriptor.params == {"hue_bins": 8}


def test_setting_the_same_plugin_keeps_its_params() -> None:
    raw = apply_overrides(small_synthetic_recipe(), ["descriptor.plugin=downsampled"])
    assert raw["descriptor"]["params"] == {"width": 16, "height": 16}


def test_max_frames_before_the_first_query_warns(cli, write_recipe, tmp_path: Path) -> None:
    # 40 reference frames, then the queries: 30 frames never reach one
    code, stdout, err = cli("run", write_recipe(small_synthetic_recipe()), "-o", tmp_path / "out", "-q",
                            "--max-frames", "30")
    assert code == 0 and "report:" in stdout
    assert "slamfront: warning: --max-frames 30 stops the run before frame 40, the first query frame with a true " \
           "match: no query is scored (recall will be 0)" in err
    warnings = [m.decoded for m in read_messages(tmp_path / "out" / "run.mcap", ["/log"]) if "--max-frames" in m.decoded.message]
    assert len(warnings) == 1 and warnings[0].name == "slamfront.runtime"


def test_max_frames_that_reaches_queries_says_nothing(cli, write_recipe, tmp_path: Path) -> None:
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "-o", tmp_path / "out", "-q", "--max-frames", "45")
    assert code == 0 and "warning" not in err


def _failing_at(frame: int, error: BaseException):
    process = NearestNeighbour.process

    def failing(self: NearestNeighbour, inputs: Any) -> Any:
        if inputs.frame.index == frame:
            raise error
        return process(self, inputs)

    return failing


def test_bad_input_mid_run_names_the_partial_log(cli, write_recipe, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(NearestNeighbour, "process", _failing_at(12, DataError("img/012.png: cannot read image")))
    out = tmp_path / "out"
    line = _one_line_error(*cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q")[::2])
    assert line == f"slamfront: error: img/012.png: cannot read image (the log written so far: {out / 'run.mcap'})"


def test_a_plugin_exception_prints_its_traceback_and_the_partial_log(
    cli, write_recipe, tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setattr(NearestNeighbour, "process", _failing_at(7, ValueError("boom")))
    out = tmp_path / "out"
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q")
    assert code == 1
    assert "Traceback" in err and 'raise error' in err  # the plugin author needs where it came from
    assert err.strip().splitlines()[-1] == (
        "slamfront: error: the run failed in the loop_detector plugin 'nearest_neighbour' at frame 7: "
        f"ValueError: boom; the log written so far is finalised: {out / 'run.mcap'}"
    )
    assert (out / "run.mcap").is_file()


def test_an_interrupted_run_names_its_log(cli, write_recipe, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(NearestNeighbour, "process", _failing_at(5, KeyboardInterrupt()))
    out = tmp_path / "out"
    code, _, err = cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q")
    assert code == 130
    assert err.strip() == f"slamfront: interrupted (SIGINT); the log written so far is finalised: {out / 'run.mcap'}"


def test_a_replay_failure_names_the_new_partial_log(cli, write_recipe, tmp_path: Path, monkeypatch) -> None:
    first = tmp_path / "first"
    assert cli("run", write_recipe(small_synthetic_recipe()), "-o", first, "-q")[0] == 0
    monkeypatch.setattr(NearestNeighbour, "process", _failing_at(50, ValueError("boom")))
    code, _, err = cli("replay", first, "-o", tmp_path / "again", "-q")
    assert code == 1 and err.strip().endswith(f"finalised: {tmp_path / 'again' / 'run.mcap'}")


def _complete(line: str, tmp_path: Path) -> list[str]:
    """What the shell would offer for ``line`` (argcomplete's protocol, as bash drives it)."""
    target = tmp_path / "completions.txt"
    env = {
        **os.environ, "_ARGCOMPLETE": "1", "COMP_LINE": line, "COMP_POINT": str(len(line)),
        "_ARGCOMPLETE_STDOUT_FILENAME": str(target), "_ARGCOMPLETE_IFS": "\n",
    }
    subprocess.run([sys.executable, "-m", "slamfront"], env=env, check=True, cwd=tmp_path, timeout=120)
    return [c.strip() for c in target.read_text().split("\n")]


def test_shell_completion(tmp_path: Path) -> None:
    assert "run" in _complete("slamfront ru", tmp_path)
    assert "demo" in _complete("slamfront run de", tmp_path)
    assert _complete("slamfront run paired_demo --set loop_detector.params.uniq", tmp_path) == [
        "loop_detector.params.uniqueness_window="
    ]
    assert {"log.images=", "log.image_max_width=", "log.image_format="} <= set(
        _complete("slamfront run demo --set log.im", tmp_path)
    )


def test_shell_completion_is_documented() -> None:
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert 'eval "$(register-python-argcomplete slamfront)"' in readme


def _sub_parsers() -> dict[str, Any]:
    parser = build_parser()
    return dict(parser._subparsers._group_actions[0].choices)  # noqa: SLF001 - argparse keeps them here


def _parsers(parser: argparse.ArgumentParser, name: str = "slamfront") -> dict[str, argparse.ArgumentParser]:
    """Every (sub-)parser of the CLI, by its command line."""
    found = {name: parser}
    for action in parser._actions:  # noqa: SLF001
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub_name, sub in action.choices.items():
                found.update(_parsers(sub, f"{name} {sub_name}"))
    return found


def test_help_texts_have_no_literal_percent_signs_and_every_argument_is_explained() -> None:
    for name, parser in _parsers(build_parser()).items():
        assert "%%" not in parser.format_help(), name
        for action in parser._actions:  # noqa: SLF001
            assert action.help, f"{name}: {action.dest} has no help"


def test_compare_and_datasets_help() -> None:
    sub = _sub_parsers()
    assert "recall at 100 % precision" in sub["compare"].format_help()
    assert "download NAME: fetch a source's dataset" in " ".join(sub["datasets"].format_help().split())


def test_time_per_stage_includes_the_source(cli, write_recipe, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert cli("run", write_recipe(small_synthetic_recipe()), "-o", out, "-q")[0] == 0
    timing = json.loads((out / "metrics.json").read_text())["timing"]
    assert list(timing)[0] == "source" and timing["source"]["total_s"] > 0
    assert "| source |" in (out / "report.md").read_text()
