"""Plots and Markdown for pose-graph results (``slamfront optimize``, the outlier study,
the back end's run report)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slamfront.core.alignment import apply, umeyama
from slamfront.report.plots import _pyplot


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
    """
    from matplotlib.collections import LineCollection

    plt = _pyplot()
    shown = {name: aligned_to(points, ground_truth) for name, points in panels.items()}
    stacked = np.concatenate([*shown.values(), *(() if ground_truth is None else (ground_truth,))])
    a, b = _plane(stacked)
    fig, axes = plt.subplots(1, len(shown), figsize=(5.2 * len(shown), 5), dpi=110, squeeze=False)
    for ax, (name, points) in zip(axes[0], shown.items()):
        if ground_truth is not None:
            ax.plot(ground_truth[:, a], ground_truth[:, b], color="0.6", linewidth=1.6, label="ground truth")
        if loops is not None and len(loops):  # long before optimisation (the gap), short after
            segments = points[loops][:, :, [a, b]]
            ax.add_collection(LineCollection(segments, colors="tab:red", linewidths=0.8, alpha=0.6,
                                             label=f"loop closures ({len(loops)})"))
        ax.plot(points[:, a], points[:, b], color="tab:blue", linewidth=0.8, label="estimate")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("xyz"[a] + " [m]")
        ax.set_ylabel("xyz"[b] + " [m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def metrics_table(metrics: Mapping[str, Any], keys: Sequence[str] | None = None) -> str:
    """A two-column Markdown table of scalar metrics."""
    rows = ["| metric | value |", "| --- | --- |"]
    for key in keys or list(metrics):
        if key in metrics and not isinstance(metrics[key], (dict, list)):
            value = metrics[key]
            rows.append(f"| {key} | {value:.6g} |" if isinstance(value, float) else f"| {key} | {value} |")
    return "\n".join(rows)
