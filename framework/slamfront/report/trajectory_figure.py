"""Trajectory panels drawn with Pillow: the before/after figure of ``slamfront optimize``.

Importing matplotlib alone (~0.3-0.4 s of CPU) costs more than reading and optimising
a pose graph of a few thousand poses with GTSAM, and drawing two such panels with it
another ~0.25 s: the figure doubled the command's run. Pillow imports in ~15 ms and
draws the same panels (polylines, segments, axes with round-number ticks, a grid, titles
and a legend) in a few tens of milliseconds: one-pixel lines (not anti-aliased), the loop
closures in a light red so that thousands of them do not hide the trajectory.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SCALE = 1
"""Drawn at this multiple of the final size, then reduced: 2 smooths the lines (anti-aliasing)
but costs ~15 ms more on two panels of a few thousand poses and loop closures."""

PANEL_SIZE = (560, 540)
"""One panel's width and height in the written image, pixels."""

Colour = tuple[int, int, int]
BLUE: Colour = (31, 119, 180)
RED_LIGHT: Colour = (230, 125, 126)  # matplotlib's tab:red at 60 % over white
GREY: Colour = (153, 153, 153)
GRID: Colour = (231, 231, 231)


@dataclass(frozen=True)
class Layer:
    """Something a panel draws: a polyline through (N, 2) points, or (L, 2, 2) segments."""

    label: str
    colour: Colour
    width: float
    """Line width in pixels of the written image."""
    points: np.ndarray


@dataclass(frozen=True)
class Panel:
    """One set of axes: layers drawn in order (the last on top), with equal scales on x and y."""

    title: str
    xlabel: str
    ylabel: str
    layers: Sequence[Layer]


def ticks(low: float, high: float, most: int = 6) -> tuple[np.ndarray, float]:
    """Round-number tick positions within [low, high] (at most about ``most``) and their step."""
    span = high - low
    if not span > 0:
        return np.array([low]), 1.0
    raw = span / most
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw * (1 - 1e-9))
    first = math.ceil(low / step - 1e-9) * step
    return np.arange(first, high + step * 1e-6, step), step


def tick_label(value: float, step: float) -> str:
    """``value`` with as many decimals as the tick step needs (no ``-0``)."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if decimals and round(step * 10**decimals) % 10 and not float(f"{step:.{decimals}f}") == step:
        decimals += 1  # steps like 0.25
    text = f"{value:.{decimals}f}"
    return "0" if float(text) == 0 else text


def _fonts(scale: int) -> dict[str, Any]:
    from PIL import ImageFont

    return {name: ImageFont.load_default(size=size * scale) for name, size in
            (("tick", 10), ("label", 11), ("legend", 9), ("title", 11), ("suptitle", 12))}


def _limits(layers: Sequence[Layer], box: tuple[float, float]) -> tuple[float, float, float, float]:
    """x0, x1, y0, y1 covering every layer, padded, with equal scales in a box (w, h)."""
    points = np.concatenate([layer.points.reshape(-1, 2) for layer in layers if layer.points.size])
    points = points[np.all(np.isfinite(points), axis=1)]
    if not len(points):
        points = np.zeros((1, 2))
    low, high = points.min(axis=0), points.max(axis=0)
    centre, half = (low + high) / 2, np.maximum((high - low) / 2 * 1.05, 1e-9)
    scale = min(box[0] / (2 * half[0]), box[1] / (2 * half[1]))  # pixels per metre
    half = np.array([box[0], box[1]]) / (2 * scale)  # widen the other axis to fill the box
    return centre[0] - half[0], centre[0] + half[0], centre[1] - half[1], centre[1] + half[1]


def _draw_panel(image: Any, panel: Panel, origin: tuple[int, int], fonts: dict[str, Any], s: int) -> None:
    from PIL import Image, ImageDraw

    draw = ImageDraw.Draw(image)
    width, height = PANEL_SIZE[0] * s, PANEL_SIZE[1] * s
    left, top = origin[0] + 72 * s, origin[1] + 26 * s
    right, bottom = origin[0] + width - 14 * s, origin[1] + height - 46 * s
    x0, x1, y0, y1 = _limits(panel.layers, (right - left, bottom - top))
    sx, sy = (right - left) / (x1 - x0), (bottom - top) / (y1 - y0)

    def pixels(points: np.ndarray) -> np.ndarray:
        out = np.empty(points.shape)
        out[..., 0] = left + (points[..., 0] - x0) * sx
        out[..., 1] = bottom - (points[..., 1] - y0) * sy
        return out

    xs, x_step = ticks(x0, x1)
    ys, y_step = ticks(y0, y1)
    for x in pixels(np.column_stack([xs, np.full(len(xs), y0)]))[:, 0]:
        draw.line([(x, top), (x, bottom)], fill=GRID, width=s)
        draw.line([(x, bottom), (x, bottom + 4 * s)], fill=(0, 0, 0), width=s)
    for y in pixels(np.column_stack([np.full(len(ys), x0), ys]))[:, 1]:
        draw.line([(left, y), (right, y)], fill=GRID, width=s)
        draw.line([(left - 4 * s, y), (left, y)], fill=(0, 0, 0), width=s)
    for value, x in zip(xs, pixels(np.column_stack([xs, np.full(len(xs), y0)]))[:, 0]):
        draw.text((x, bottom + 6 * s), tick_label(value, x_step), fill=(0, 0, 0), font=fonts["tick"], anchor="mt")
    for value, y in zip(ys, pixels(np.column_stack([np.full(len(ys), x0), ys]))[:, 1]):
        draw.text((left - 6 * s, y), tick_label(value, y_step), fill=(0, 0, 0), font=fonts["tick"], anchor="rm")

    for layer in panel.layers:  # clipped to the axes: limits cover the data, but not NaNs
        drawn = pixels(layer.points)
        line_width = max(1, round(layer.width * s))
        if layer.points.ndim == 3:  # thousands of loop closures: Pillow's line() once per segment
            for segment in drawn[np.all(np.isfinite(drawn), axis=(1, 2))].reshape(-1, 4).tolist():
                draw.line(segment, fill=layer.colour, width=line_width)
        elif len(drawn) > 1:
            draw.line(drawn[np.all(np.isfinite(drawn), axis=1)].ravel().tolist(), fill=layer.colour, width=line_width)
    draw.rectangle([left, top, right, bottom], outline=(0, 0, 0), width=s)

    draw.text(((left + right) / 2, origin[1] + 6 * s), panel.title, fill=(0, 0, 0), font=fonts["title"], anchor="mt")
    draw.text(((left + right) / 2, bottom + 24 * s), panel.xlabel, fill=(0, 0, 0), font=fonts["label"], anchor="mt")
    label_box = draw.textbbox((0, 0), panel.ylabel, font=fonts["label"])
    label = Image.new("RGB", (label_box[2] + 2 * s, label_box[3] + 2 * s), "white")
    ImageDraw.Draw(label).text((s, s), panel.ylabel, fill=(0, 0, 0), font=fonts["label"])
    label = label.rotate(90, expand=True)
    image.paste(label, (origin[0] + 4 * s, int((top + bottom) / 2 - label.height / 2)))
    _legend(draw, panel.layers, (left, top, right, bottom), [pixels(layer.points) for layer in panel.layers], fonts, s)


def _legend(draw: Any, layers: Sequence[Layer], box: tuple[float, float, float, float],
            drawn: list[np.ndarray], fonts: dict[str, Any], s: int) -> None:
    """A legend in the corner of ``box`` that hides the fewest drawn points."""
    entries = [layer for layer in layers if layer.label]
    if not entries:
        return
    row = 14 * s
    text_width = max(draw.textlength(layer.label, font=fonts["legend"]) for layer in entries)
    width, height = 30 * s + text_width + 10 * s, row * len(entries) + 8 * s
    left, top, right, bottom = box
    corners = [(left + 6 * s, top + 6 * s), (right - 6 * s - width, top + 6 * s),
               (left + 6 * s, bottom - 6 * s - height), (right - 6 * s - width, bottom - 6 * s - height)]
    points = np.concatenate([d.reshape(-1, 2) for d in drawn])

    def hidden(corner: tuple[float, float]) -> int:
        inside = (points[:, 0] >= corner[0]) & (points[:, 0] <= corner[0] + width)
        return int(np.sum(inside & (points[:, 1] >= corner[1]) & (points[:, 1] <= corner[1] + height)))

    x, y = min(corners, key=hidden)
    draw.rectangle([x, y, x + width, y + height], fill=(255, 255, 255), outline=(204, 204, 204), width=s)
    for k, layer in enumerate(entries):
        middle = y + 4 * s + row * k + row / 2
        draw.line([(x + 6 * s, middle), (x + 26 * s, middle)], fill=layer.colour, width=max(1, round(layer.width * s)))
        draw.text((x + 32 * s, middle), layer.label, fill=(0, 0, 0), font=fonts["legend"], anchor="lm")


def draw_panels(panels: Sequence[Panel], path: Path, title: str = "") -> Path:
    """Draw ``panels`` side by side under ``title`` and write a PNG (through a temporary file)."""
    from PIL import Image, ImageDraw

    s = SCALE
    band = 24 * s if title else 0
    image = Image.new("RGB", (PANEL_SIZE[0] * s * len(panels), PANEL_SIZE[1] * s + band), "white")
    fonts = _fonts(s)
    if title:
        ImageDraw.Draw(image).text((image.width / 2, 6 * s), title, fill=(0, 0, 0), font=fonts["suptitle"], anchor="mt")
    for k, panel in enumerate(panels):
        _draw_panel(image, panel, (PANEL_SIZE[0] * s * k, band), fonts, s)
    image = image.reduce(s)
    tmp = Path(path).with_name(Path(path).name + ".tmp")  # never half a PNG under the real name
    try:
        image.save(tmp, format="PNG", compress_level=1)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    return Path(path)
