"""Plots and Markdown for pose-graph results (``slamfront optimize``, the outlier study,
the back end's run report)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slamfront.core.alignment import apply, umeyama
from slamfront.report.trajectory_figure import BLUE, GREY, RED_LIGHT, Layer, Panel, draw_panels


def aligned_to(points: np.ndarray, ground_truth: np.ndarray | None) -> np.ndarray:
    """``points`` moved onto ``ground_truth`` by the rigid motion ATE uses (as given without it)."""
    if ground_truth is None:
        return points
    return apply(points, *umeyama(points, ground_truth))


def _plane(stacked: np.ndarray) -> tuple[int, int]:
    if stacked.shape[1] == 2:
        return 0, 1
    spread = np.ptp(stacked, axis=0)
    best = np.argsort(spread)[::-1][:2]
    return int(min(best)), int(max(best))


def before_after(
    panels: Mapping[str, np.ndarray],
    path: Path,
    ground_truth: np.ndarray | None = None,
    loops: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """One panel per estimate (``{title: (N, d) positions}``), each over the ground truth.

    Estimates are aligned to the ground truth (as for the ATE) so they overlay it; loop
    closures ``loops`` (L, 2) vertex positions are drawn as lines on every panel, with
    their count in the legend. The view is the plane the trajectory spreads in most.
    Written as SVG when ``path`` ends in ``.svg`` (no imaging library), else as a PNG
    drawn with Pillow (:mod:`slamfront.report.trajectory_figure`: matplotlib's import
    alone costs more than optimising a graph of a few thousand poses).
    """
    shown = {name: aligned_to(points, ground_truth) for name, points in panels.items()}
    stacked = np.concatenate([*shown.values(), *(() if ground_truth is None else (ground_truth,))])
    a, b = _plane(stacked)
    drawn = []
    for name, points in shown.items():
        layers = []
        if ground_truth is not None:
            layers.append(Layer("ground truth", GREY, 1.6, ground_truth[:, [a, b]]))
        if loops is not None and len(loops):  # long before optimisation (the gap), short after
            layers.append(Layer(f"loop closures ({len(loops)})", RED_LIGHT, 1.0, points[loops][:, :, [a, b]]))
        layers.append(Layer("estimate", BLUE, 1.0, points[:, [a, b]]))
        drawn.append(Panel(name, "xyz"[a] + " [m]", "xyz"[b] + " [m]", layers))
    return draw_panels(drawn, path, title)


def metrics_table(metrics: Mapping[str, Any], keys: Sequence[str] | None = None) -> str:
    """A two-column Markdown table of scalar metrics."""
    rows = ["| metric | value |", "| --- | --- |"]
    for key in keys or list(metrics):
        if key in metrics and not isinstance(metrics[key], (dict, list)):
            value = metrics[key]
            rows.append(f"| {key} | {value:.6g} |" if isinstance(value, float) else f"| {key} | {value} |")
    return "\n".join(rows)
