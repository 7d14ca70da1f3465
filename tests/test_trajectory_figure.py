"""The Pillow figure of ``slamfront optimize``: round-number ticks and a readable PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from slamfront.report.trajectory_figure import BLUE, Layer, Panel, draw_panels, tick_label, ticks


@pytest.mark.parametrize(
    ("low", "high", "expected"),
    [(0.0, 10.0, [0, 2, 4, 6, 8, 10]), (-0.37, 0.41, [-0.2, 0.0, 0.2, 0.4]), (1234.0, 1236.5, [1234, 1234.5, 1235, 1235.5, 1236, 1236.5])],
)
def test_ticks_are_round_numbers_inside_the_range(low: float, high: float, expected: list[float]) -> None:
    positions, step = ticks(low, high)
    np.testing.assert_allclose(positions, expected, atol=1e-9)
    assert [tick_label(v, step) for v in positions[:2]] == [tick_label(e, step) for e in expected[:2]]


def test_tick_labels_have_the_decimals_the_step_needs() -> None:
    assert tick_label(-0.0, 0.2) == "0" and tick_label(0.4, 0.2) == "0.4" and tick_label(0.25, 0.25) == "0.25"
    assert tick_label(1500.0, 500.0) == "1500"


def test_panels_are_written_as_a_png_through_a_temporary_file(tmp_path: Path) -> None:
    angle = np.linspace(0, 2 * np.pi, 200)
    circle = np.column_stack([np.cos(angle), np.sin(angle)]) * 40
    loops = np.stack([circle[:100:10], circle[100::10]], axis=1)
    panels = [Panel(f"panel {k}", "x [m]", "y [m]", [Layer("loops", (230, 125, 126), 1, loops),
                                                     Layer("estimate", BLUE, 1, circle)]) for k in range(2)]
    path = draw_panels(panels, tmp_path / "figure.png", title="two circles")
    with Image.open(path) as image:
        assert image.format == "PNG" and image.width > image.height
        pixels = np.asarray(image.convert("RGB"))
    assert np.any(np.all(pixels == BLUE, axis=-1))  # the estimate is drawn
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.png"]
