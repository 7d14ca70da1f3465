"""PNG plots for run reports. Matplotlib runs headless (Agg) and is imported lazily."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pr_curves(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "") -> Path:
    """Precision-recall curves, one per label: ``{label: (recall, precision)}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    for label, (recall, precision) in curves.items():
        ax.step(np.r_[0.0, recall], np.r_[1.0, precision], where="post", label=label)
    ax.set_xlim(0, 1.0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_title(title or "precision-recall")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def match_plot(
    query: np.ndarray,
    match: np.ndarray,
    confidence: np.ndarray,
    correct: np.ndarray,
    truth_lo: np.ndarray,
    truth_hi: np.ndarray,
    path: Path,
    title: str = "",
    xlabel: str = "query frame",
    ylabel: str = "matched reference frame",
) -> Path:
    """Chosen reference vs query over the ground-truth band, coloured by confidence.

    :param query: (N,) x positions; ``match`` (N,) y positions (NaN for no answer).
    :param truth_lo: (N,) / ``truth_hi`` (N,) the band of correct matches (NaN: none).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5), dpi=110)
    order = np.argsort(query)
    ax.fill_between(
        query[order], truth_lo[order], truth_hi[order], color="tab:green", alpha=0.25, step="mid",
        label="ground truth (within tolerance)", linewidth=0,
    )
    answered = np.isfinite(match)
    good = answered & correct
    bad = answered & ~correct
    scatter = ax.scatter(
        query[good], match[good], c=confidence[good], cmap="viridis", vmin=0, vmax=1, s=8, label="correct"
    )
    ax.scatter(
        query[bad], match[bad], c=confidence[bad], cmap="viridis", vmin=0, vmax=1, s=22, marker="x",
        label="wrong",
    )
    fig.colorbar(scatter, ax=ax, label="confidence")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title or "matches")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def trajectories_2d(
    paths: Mapping[str, np.ndarray], path: Path, title: str = "", markers: Sequence[np.ndarray] = ()
) -> Path:
    """Top view (x, y) of one or more trajectories: ``{label: (N, 3) positions}``.

    The plane is the one the trajectories spread in most (x-y, or x-z for camera
    conventions with y down).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 5), dpi=110)
    stacked = np.concatenate([p for p in paths.values() if len(p)] or [np.zeros((1, 3))])
    spread = np.ptp(stacked, axis=0)
    a, b = (0, 1) if spread[1] >= spread[2] else (0, 2)
    for label, points in paths.items():
        if len(points):
            ax.plot(points[:, a], points[:, b], label=label, linewidth=1.2)
    for segment in markers:
        ax.plot(segment[:, a], segment[:, b], color="tab:red", linewidth=0.6, alpha=0.6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("xyz"[a] + " [m]")
    ax.set_ylabel("xyz"[b] + " [m]")
    ax.set_title(title or "trajectory")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def series_panels(
    panels: Sequence[tuple[str, Mapping[str, tuple[np.ndarray, np.ndarray]], Mapping[str, float]]],
    path: Path,
    title: str = "",
    xlabel: str = "frame",
) -> Path:
    """Stacked line plots sharing the x axis, one per ``(y label, {label: (x, y)}, {line label: y})``.

    The last mapping draws horizontal reference lines (a threshold, a time budget).
    """
    plt = _pyplot()
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.4 * len(panels) + 0.6), dpi=110, sharex=True, squeeze=False)
    for ax, (ylabel, series, lines) in zip(axes[:, 0], panels):
        for label, (x, y) in series.items():
            ax.plot(x, y, label=label, linewidth=0.9)
        for label, value in lines.items():
            ax.axhline(value, color="tab:red", linestyle="--", linewidth=0.9, label=label)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if len(series) + len(lines) > 1:
            ax.legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel(xlabel)
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
