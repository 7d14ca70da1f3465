"""Shared fixtures. Real data comes from ../shared/data (or $SLAMFRONT_DATA)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront.cli import main
from slamfront.data import data_root


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real-data root; its absence is a failure, not a skip (see README, Tests)."""
    root = data_root()
    assert root.is_dir(), f"real data not found at {root}: set SLAMFRONT_DATA or put ../shared/data beside the checkout"
    return root


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]):
    """Run the slamfront CLI in-process: returns (exit code, stdout, stderr)."""

    def invoke(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return invoke


def small_synthetic_recipe(**source_params: Any) -> dict[str, Any]:
    """A recipe dict for a quick synthetic run (few, small frames)."""
    params = {"frames_per_traversal": 40, "route_length_m": 80, "image_width": 64, "image_height": 48}
    params.update(source_params)
    return {
        "name": "small",
        "source": {"plugin": "synthetic", "params": params},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {}},
        "eval": {"plots": False},
    }


@pytest.fixture
def write_recipe(tmp_path: Path):
    """Write a recipe dict to a YAML file in tmp_path and return its path."""

    def write(recipe: dict[str, Any], name: str = "recipe.yaml") -> Path:
        path = tmp_path / name
        path.write_text(yaml.safe_dump(recipe))
        return path

    return write
