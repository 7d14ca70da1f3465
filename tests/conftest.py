"""Shared fixtures. Real data comes from the data root (``slamfront datasets path``; docs/data.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from slamfront.cli import main
from slamfront.data import data_root

SLOW = {
    # the longest tests without real data (`pytest --durations`, a shared 2-core machine at
    # load ~12: 30-185 s each there, 10-50 s on an idle one); `-m "not slow"` leaves them out
    "tests/test_keyframe_localizer.py::test_kidnapped_robot_localizes_in_its_region_and_refuses_unknown_places",
    "tests/test_keyframe_localizer.py::test_run_outputs_metrics_log_report_and_trajectories",
    "tests/test_keyframe_localizer.py::test_the_papers_matching_with_sift_runs_to_the_end",
    "tests/test_demo.py::test_the_demo_prints_ate_before_and_after_and_the_report_page_twice",
    "tests/test_demo.py::test_the_demo_verifies_closures_and_optimises_image_odometry",
    "tests/test_demo.py::test_the_demo_log_opens_with_the_shipped_layout",
    "tests/test_campaign.py::test_pool_and_ray_give_identical_tables",
    "tests/test_campaign.py::test_interrupted_campaign_resumes_without_redoing_finished_runs",
    "tests/test_log_validity.py::test_localization_and_registration_layouts_show_topics_their_logs_have",
    "tests/test_packaging.py::test_the_wheel_installs_and_runs_from_any_directory",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that asks for the real data is a ``realdata`` test: ``-m "not realdata"`` leaves it
    out; the tests of :data:`SLOW` are ``slow`` ones."""
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.realdata)
        if item.nodeid.split("[")[0] in SLOW:
            item.add_marker(pytest.mark.slow)


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
