"""Trajectory panels: the before/after figure of ``slamfront optimize`` (SVG) and of the
pose-graph back end's run report (PNG).

Importing matplotlib alone (~0.3-0.4 s of CPU) costs more than reading and optimising
a pose graph of a few thousand poses with GTSAM, and drawing two such panels with it
another ~0.25 s: the figure doubled the command's run. Both writers here share one
layout (equal axis scales, round-number ticks, a grid, titles, a legend in the corner
that hides the fewest points):

- ``.svg``: the panels as SVG text (polylines and paths, text set by the viewer), built
  from the arrays with no imaging library at all; a few milliseconds for two panels of
  thousands of poses and loop closures, and the lines stay sharp when zoomed;
- ``.png``: drawn with Pillow (imports in ~15 ms, draws in a few tens of milliseconds):
  one-pixel lines (not anti-aliased), the loop closures in a light red so that thousands
  of them do not hide the trajectory.
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

    return {name: ImageFont.load_default(size=size * scale) for name, size in FONT_SIZES.items()}


FONT_SIZES = {"tick": 10, "label": 11, "legend": 9, "title": 11, "suptitle": 12}
"""Text sizes in pixels of the written image."""


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


@dataclass(frozen=True)
class _Axes:
    """Where one panel's axes sit in the image (pixels) and the metres they show."""

    left: float
    top: float
    right: float
    bottom: float
    x0: float
    x1: float
    y0: float
    y1: float

    @classmethod
    def of(cls, panel: Panel, origin: tuple[float, float], s: int) -> _Axes:
        left, top = origin[0] + 72 * s, origin[1] + 26 * s
        right, bottom = origin[0] + PANEL_SIZE[0] * s - 14 * s, origin[1] + PANEL_SIZE[1] * s - 46 * s
        return cls(left, top, right, bottom, *_limits(panel.layers, (right - left, bottom - top)))

    def pixels(self, points: np.ndarray) -> np.ndarray:
        """Metres (..., 2) -> image pixels (..., 2), y downwards."""
        out = np.empty(np.shape(points))
        out[..., 0] = self.left + (points[..., 0] - self.x0) * ((self.right - self.left) / (self.x1 - self.x0))
        out[..., 1] = self.bottom - (points[..., 1] - self.y0) * ((self.bottom - self.top) / (self.y1 - self.y0))
        return out

    def ticks(self) -> tuple[list[tuple[float, str]], list[tuple[float, str]]]:
        """(pixel x, label) of the x ticks and (pixel y, label) of the y ticks."""
        xs, x_step = ticks(self.x0, self.x1)
        ys, y_step = ticks(self.y0, self.y1)
        x_pixels = self.pixels(np.column_stack([xs, np.full(len(xs), self.y0)]))[:, 0]
        y_pixels = self.pixels(np.column_stack([np.full(len(ys), self.x0), ys]))[:, 1]
        return ([(float(x), tick_label(v, x_step)) for v, x in zip(xs, x_pixels)],
                [(float(y), tick_label(v, y_step)) for v, y in zip(ys, y_pixels)])


def _finite(drawn: np.ndarray) -> np.ndarray:
    """The points (N, 2) or segments (L, 2, 2) with every coordinate finite."""
    return drawn[np.all(np.isfinite(drawn), axis=(1, 2) if drawn.ndim == 3 else 1)]


def _legend_box(axes: _Axes, drawn: list[np.ndarray], n_entries: int, text_width: float, s: int) -> tuple[float, ...]:
    """x, y, width, height of a legend of ``n_entries`` rows in the corner of the axes that
    hides the fewest ``drawn`` points (pixels)."""
    width, height = 30 * s + text_width + 10 * s, LEGEND_ROW * s * n_entries + 8 * s
    corners = [(axes.left + 6 * s, axes.top + 6 * s), (axes.right - 6 * s - width, axes.top + 6 * s),
               (axes.left + 6 * s, axes.bottom - 6 * s - height), (axes.right - 6 * s - width, axes.bottom - 6 * s - height)]
    points = np.concatenate([d.reshape(-1, 2) for d in drawn])

    def hidden(corner: tuple[float, float]) -> int:
        inside = (points[:, 0] >= corner[0]) & (points[:, 0] <= corner[0] + width)
        return int(np.sum(inside & (points[:, 1] >= corner[1]) & (points[:, 1] <= corner[1] + height)))

    x, y = min(corners, key=hidden)
    return x, y, width, height


LEGEND_ROW = 14
"""Height of a legend row, pixels."""


def _draw_panel(image: Any, panel: Panel, origin: tuple[int, int], fonts: dict[str, Any], s: int) -> None:
    from PIL import Image, ImageDraw

    draw = ImageDraw.Draw(image)
    axes = _Axes.of(panel, origin, s)
    left, top, right, bottom = axes.left, axes.top, axes.right, axes.bottom
    x_ticks, y_ticks = axes.ticks()
    for x, _ in x_ticks:
        draw.line([(x, top), (x, bottom)], fill=GRID, width=s)
        draw.line([(x, bottom), (x, bottom + 4 * s)], fill=(0, 0, 0), width=s)
    for y, _ in y_ticks:
        draw.line([(left, y), (right, y)], fill=GRID, width=s)
        draw.line([(left - 4 * s, y), (left, y)], fill=(0, 0, 0), width=s)
    for x, text in x_ticks:
        draw.text((x, bottom + 6 * s), text, fill=(0, 0, 0), font=fonts["tick"], anchor="mt")
    for y, text in y_ticks:
        draw.text((left - 6 * s, y), text, fill=(0, 0, 0), font=fonts["tick"], anchor="rm")

    drawn = [axes.pixels(layer.points) for layer in panel.layers]
    for layer, pixels in zip(panel.layers, drawn):  # limits cover the data, but not NaNs
        line_width = max(1, round(layer.width * s))
        if layer.points.ndim == 3:  # thousands of loop closures: Pillow's line() once per segment
            for segment in _finite(pixels).reshape(-1, 4).tolist():
                draw.line(segment, fill=layer.colour, width=line_width)
        elif len(pixels) > 1:
            draw.line(_finite(pixels).ravel().tolist(), fill=layer.colour, width=line_width)
    draw.rectangle([left, top, right, bottom], outline=(0, 0, 0), width=s)

    draw.text(((left + right) / 2, origin[1] + 6 * s), panel.title, fill=(0, 0, 0), font=fonts["title"], anchor="mt")
    draw.text(((left + right) / 2, bottom + 24 * s), panel.xlabel, fill=(0, 0, 0), font=fonts["label"], anchor="mt")
    label_box = draw.textbbox((0, 0), panel.ylabel, font=fonts["label"])
    label = Image.new("RGB", (label_box[2] + 2 * s, label_box[3] + 2 * s), "white")
    ImageDraw.Draw(label).text((s, s), panel.ylabel, fill=(0, 0, 0), font=fonts["label"])
    label = label.rotate(90, expand=True)
    image.paste(label, (origin[0] + 4 * s, int((top + bottom) / 2 - label.height / 2)))
    entries = [layer for layer in panel.layers if layer.label]
    if not entries:
        return
    text_width = max(draw.textlength(layer.label, font=fonts["legend"]) for layer in entries)
    x, y, width, height = _legend_box(axes, drawn, len(entries), text_width, s)
    draw.rectangle([x, y, x + width, y + height], fill=(255, 255, 255), outline=(204, 204, 204), width=s)
    for k, layer in enumerate(entries):
        middle = y + 4 * s + LEGEND_ROW * s * k + LEGEND_ROW * s / 2
        draw.line([(x + 6 * s, middle), (x + 26 * s, middle)], fill=layer.colour, width=max(1, round(layer.width * s)))
        draw.text((x + 32 * s, middle), layer.label, fill=(0, 0, 0), font=fonts["legend"], anchor="lm")


def draw_panels(panels: Sequence[Panel], path: Path, title: str = "") -> Path:
    """Draw ``panels`` side by side under ``title`` and write them (through a temporary
    file): SVG when ``path`` ends in ``.svg``, else PNG."""
    path = Path(path)
    if path.suffix.lower() == ".svg":
        return _write_through_temporary(path, lambda tmp: tmp.write_text(svg_panels(panels, title), encoding="utf-8"))
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
    return _write_through_temporary(path, lambda tmp: image.save(tmp, format="PNG", compress_level=1))


def _write_through_temporary(path: Path, write: Any) -> Path:
    tmp = path.with_name(path.name + ".tmp")  # never half a figure under the real name
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    return path


# --- SVG ------------------------------------------------------------------------------


def _hex(colour: Colour) -> str:
    return "#{:02x}{:02x}{:02x}".format(*colour)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def _numbers(values: np.ndarray) -> str:
    """Pixel coordinates as text, to a tenth of a pixel (one format string for all)."""
    flat = np.round(np.asarray(values, dtype=np.float64).ravel(), 1).tolist()
    return ("%g " * len(flat) % tuple(flat)).rstrip()


def _text(x: float, y: float, text: str, size: int, anchor: str = "middle", baseline: str = "hanging",
          extra: str = "") -> str:
    return (f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size}" text-anchor="{anchor}" '
            f'dominant-baseline="{baseline}"{extra}>{_escape(text)}</text>')


def _svg_panel(panel: Panel, origin: tuple[float, float], index: int) -> list[str]:
    axes = _Axes.of(panel, origin, 1)
    left, top, right, bottom = axes.left, axes.top, axes.right, axes.bottom
    x_ticks, y_ticks = axes.ticks()
    grid = [f"M{x:.1f} {top:.1f}V{bottom:.1f}" for x, _ in x_ticks] + [f"M{left:.1f} {y:.1f}H{right:.1f}" for y, _ in y_ticks]
    marks = ([f"M{x:.1f} {bottom:.1f}v4" for x, _ in x_ticks] + [f"M{left - 4:.1f} {y:.1f}h4" for y, _ in y_ticks])
    out = [
        f'<clipPath id="axes{index}"><rect x="{left:.1f}" y="{top:.1f}" width="{right - left:.1f}" '
        f'height="{bottom - top:.1f}"/></clipPath>',
        f'<path d="{"".join(grid)}" stroke="{_hex(GRID)}" fill="none"/>',
        f'<path d="{"".join(marks)}" stroke="black" fill="none"/>',
        *(_text(x, bottom + 6, text, FONT_SIZES["tick"]) for x, text in x_ticks),
        *(_text(left - 6, y, text, FONT_SIZES["tick"], "end", "central") for y, text in y_ticks),
        f'<g clip-path="url(#axes{index})" fill="none" stroke-linejoin="round">',
    ]
    drawn = [axes.pixels(layer.points) for layer in panel.layers]
    for layer, pixels in zip(panel.layers, drawn):
        stroke = f'stroke="{_hex(layer.colour)}" stroke-width="{layer.width:g}"'
        finite = _finite(pixels)
        if layer.points.ndim == 3 and len(finite):  # segments: one path of move-line pairs
            out.append(f'<path {stroke} d="{_segments(finite)}"/>')
        elif layer.points.ndim == 2 and len(finite) > 1:
            out.append(f'<polyline {stroke} points="{_numbers(finite)}"/>')
    out += [
        "</g>",
        f'<rect x="{left:.1f}" y="{top:.1f}" width="{right - left:.1f}" height="{bottom - top:.1f}" fill="none" '
        'stroke="black"/>',
        _text((left + right) / 2, origin[1] + 6, panel.title, FONT_SIZES["title"]),
        _text((left + right) / 2, bottom + 24, panel.xlabel, FONT_SIZES["label"]),
        _text(origin[0] + 10, (top + bottom) / 2, panel.ylabel, FONT_SIZES["label"], "middle", "central",
              f' transform="rotate(-90 {origin[0] + 10:.1f} {(top + bottom) / 2:.1f})"'),
    ]
    entries = [layer for layer in panel.layers if layer.label]
    if entries:  # the viewer sets the text: its width is estimated (0.6 em a character)
        text_width = max(len(layer.label) for layer in entries) * 0.6 * FONT_SIZES["legend"]
        x, y, width, height = _legend_box(axes, drawn, len(entries), text_width, 1)
        out.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{width:.1f}" height="{height:.1f}" fill="white" '
                   f'stroke="{_hex((204, 204, 204))}"/>')
        for k, layer in enumerate(entries):
            middle = y + 4 + LEGEND_ROW * k + LEGEND_ROW / 2
            out.append(f'<path d="M{x + 6:.1f} {middle:.1f}h20" stroke="{_hex(layer.colour)}" '
                       f'stroke-width="{layer.width:g}"/>')
            out.append(_text(x + 32, middle, layer.label, FONT_SIZES["legend"], "start", "central"))
    return out


def _segments(segments: np.ndarray) -> str:
    """(L, 2, 2) pixel segments as one SVG path: ``M x y L x y`` per segment."""
    flat = np.round(segments.reshape(-1, 4), 1).ravel().tolist()
    return "M%g %gL%g %g" * len(segments) % tuple(flat)


def svg_panels(panels: Sequence[Panel], title: str = "") -> str:
    """``panels`` side by side under ``title``, as the text of an SVG image."""
    band = 24 if title else 0
    width, height = PANEL_SIZE[0] * len(panels), PANEL_SIZE[1] + band
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" '
        'font-family="DejaVu Sans, Helvetica, Arial, sans-serif">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
    ]
    if title:
        out.append(_text(width / 2, 6, title, FONT_SIZES["suptitle"]))
    for k, panel in enumerate(panels):
        out += _svg_panel(panel, (PANEL_SIZE[0] * k, band), k)
    out.append("</svg>")
    return "\n".join(out) + "\n"
