"""Shared fixtures. Real data comes from the data root (``slamfront datasets path``; docs/data.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront.cli import main
from slamfront.data import data_root


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that asks for the real data is a ``realdata`` test: ``-m "not realdata"`` leaves it out."""
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.realdata)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real-data root; its absence is a failure, not a skip (docs/data.md)."""
    root = data_root()
    assert root.is_dir(), (
        f"real data not found at {root}: run `slamfront datasets fetch --for-tests` (or `make test`, which "
        "does), or set SLAMFRONT_DATA to a folder holding it; see docs/data.md"
    )
    return root


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]):
    """Run the slamfront CLI in-process: returns (exit code, stdout, stderr)."""

    def invoke(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return invoke


@pytest.fixture
def write_recipe(tmp_path: Path):
    """Write a recipe dict to a YAML file in tmp_path and return its path."""

    def write(recipe: dict[str, Any], name: str = "recipe.yaml") -> Path:
        path = tmp_path / name
        path.write_text(yaml.safe_dump(recipe))
        return path

    return write
