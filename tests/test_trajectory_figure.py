"""The trajectory figures: round-number ticks, a readable PNG (Pillow) and a readable SVG (``slamfront optimize``)."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
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


def _two_circles() -> list[Panel]:
    angle = np.linspace(0, 2 * np.pi, 200)
    circle = np.column_stack([np.cos(angle), np.sin(angle)]) * 40
    circle[50] = np.nan  # dropped, not drawn as a coordinate
    loops = np.stack([circle[:100:10], circle[100::10]], axis=1)
    return [Panel(f"panel {k}", "x [m]", "y [m]", [Layer("loops", (230, 125, 126), 1, loops),
                                                   Layer("estimate <a&b>", BLUE, 1, circle)]) for k in range(2)]


def test_panels_are_written_as_an_svg_with_the_same_layout(tmp_path: Path) -> None:
    path = draw_panels(_two_circles(), tmp_path / "figure.svg", title="two circles")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.svg"]  # no temporary file left
    root = ElementTree.parse(path).getroot()  # well-formed XML (the labels are escaped)
    ns = {"svg": "http://www.w3.org/2000/svg"}
    assert root.tag == "{http://www.w3.org/2000/svg}svg" and int(root.get("width")) > int(root.get("height"))
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert "two circles" in texts and texts.count("estimate <a&b>") == 2 and texts.count("x [m]") == 2
    lines = root.findall(".//svg:polyline", ns)
    assert len(lines) == 2 and all(line.get("stroke") == "#1f77b4" for line in lines)
    for line in lines:
        points = np.array(line.get("points").split(), dtype=float).reshape(-1, 2)
        assert len(points) == 199 and np.all(np.isfinite(points))  # the NaN vertex dropped
        assert 72 <= points[:, 0].min() and points[:, 0].max() <= 560 * 2  # inside the figure
    loops = [p for p in root.iter("{http://www.w3.org/2000/svg}path") if p.get("stroke") == "#e67d7e"]
    assert len(loops) == 4  # segments and legend sample, on each panel
    assert any(p.get("d").count("M") == 9 for p in loops)  # the segment from the NaN vertex dropped


def test_axes_map_their_limits_onto_their_box_with_ticks_inside() -> None:
    from slamfront.report.trajectory_figure import _Axes  # the layout both writers use

    axes = _Axes.of(_two_circles()[0], (0, 0), 1)
    x_ticks, y_ticks = axes.ticks()
    assert all(axes.left <= x <= axes.right for x, _ in x_ticks) and all(axes.top <= y <= axes.bottom for y, _ in y_ticks)
    assert "0" in [label for _, label in x_ticks] and "0" in [label for _, label in y_ticks]
    np.testing.assert_allclose(axes.pixels(np.array([[axes.x0, axes.y0], [axes.x1, axes.y1]])),
                               [[axes.left, axes.bottom], [axes.right, axes.top]])
