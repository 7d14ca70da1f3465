"""Determinism: one recipe gives identical messages, in any process; `diff` finds changes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slamfront.cli import main
from slamfront.mcaplog.diff import diff_logs
from slamfront.messages import Features, LoopResult
from tests.helpers import rewrite_log, small_synthetic_recipe


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The same recipe run in this process and in a fresh one with another hash seed."""
    folder = tmp_path_factory.mktemp("determinism")
    recipe = folder / "recipe.yaml"
    raw = small_synthetic_recipe(mode="stream", laps=2, frames_per_traversal=30)
    raw["loop_detector"]["params"] = {"exclude_recent": 10}
    recipe.write_text(json.dumps(raw))
    assert main(["run", str(recipe), "-o", str(folder / "a"), "-q"]) == 0
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    command = [sys.executable, "-m", "slamfront", "run", str(recipe), "-o", str(folder / "b"), "-q"]
    subprocess.run(command, check=True, env=env, capture_output=True, timeout=300)
    return folder / "a" / "run.mcap", folder / "b" / "run.mcap"


def test_one_recipe_gives_identical_messages_across_processes(two_runs: tuple[Path, Path], cli) -> None:
    code, stdout, _ = cli("diff", *two_runs)
    assert code == 0, stdout
    assert stdout.startswith("identical:")
    result = diff_logs(*two_runs)
    assert result.messages_compared > 300 and result.topics_compared >= 12


def test_timings_differ_and_only_strict_sees_them(two_runs: tuple[Path, Path], cli) -> None:
    code, stdout, _ = cli("diff", *two_runs, "--strict")
    assert code == 1
    assert "/metrics  message 0" in stdout and "values." in stdout


def _inject(source: Path, target: Path, topic: str, index: int, edit) -> None:  # type: ignore[no-untyped-def]
    rewrite_log(source, target, lambda t, i, data: edit(data) if (t, i) == (topic, index) else data)


def test_diff_pinpoints_an_injected_change(two_runs: tuple[Path, Path], tmp_path: Path, cli) -> None:
    original = two_runs[0]

    def nudge_confidence(data: bytes) -> bytes:
        result = LoopResult.from_json(data)
        changed = LoopResult(**{**result.__dict__, "confidence": np.nextafter(result.confidence, 2.0)})
        return changed.to_json()

    changed = tmp_path / "confidence.mcap"
    _inject(original, changed, "/loop_detector/loop_result", 37, nudge_confidence)
    code, stdout, _ = cli("diff", original, changed)
    assert code == 1
    lines = stdout.strip().splitlines()
    assert lines[0].startswith("/loop_detector/loop_result  message 37 ")
    assert " confidence: " in lines[0]
    assert lines[-1].startswith("1 of ")

    def flip_one_element(data: bytes) -> bytes:
        features = Features.from_json(data)
        vector = features.vector.copy()
        vector[5] = -vector[5]
        return Features(frame=features.frame, vector=vector, metric=features.metric).to_json()

    changed = tmp_path / "vector.mcap"
    _inject(original, changed, "/descriptor/features", 3, flip_one_element)
    code, stdout, _ = cli("diff", original, changed, "--json")
    report = json.loads(stdout)
    assert code == 1 and not report["identical"]
    (difference,) = report["differences"]
    assert (difference["topic"], difference["index"], difference["field"]) == ("/descriptor/features", 3, "vector[5]")

    dropped = tmp_path / "dropped.mcap"
    rewrite_log(original, dropped, lambda t, i, data: None if (t, i) == ("/frames", 59) else data)
    result = diff_logs(original, dropped)
    assert [(d.topic, d.index) for d in result.differences] == [("/frames", 59)]
    assert "A has 60, B has 59" in result.differences[0].field


def test_diff_ignore_option(two_runs: tuple[Path, Path], tmp_path: Path) -> None:
    changed = tmp_path / "changed.mcap"
    _inject(two_runs[0], changed, "/camera/image", 0, lambda data: data[:-1] + bytes([data[-1] ^ 1]))
    assert not diff_logs(two_runs[0], changed).identical
    assert diff_logs(two_runs[0], changed, ignore=["/camera/*"]).identical
