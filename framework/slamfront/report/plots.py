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


def _finish(fig: Any, ax: Any, path: Path, title: str, xlabel: str, ylabel: str, legend: str) -> Path:
    """Labels, grid, legend; save and close."""
    plt = _pyplot()
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc=legend, fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def pr_curves(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "") -> Path:
    """Precision-recall curves, one per label: ``{label: (recall, precision)}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    for label, (recall, precision) in curves.items():
        ax.step(np.r_[0.0, recall], np.r_[1.0, precision], where="post", label=label)
    ax.set_xlim(0, 1.0)
    ax.set_ylim(0, 1.02)
    return _finish(fig, ax, path, title or "precision-recall", "recall", "precision", "lower left")


def recall_curves(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "",
    xlabel: str = "psi (nearest neighbours considered)", ylabel: str = "recall",
) -> Path:
    """Recall against the number of neighbours, one line per label: ``{label: (ks, recall)}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    for label, (ks, recall) in curves.items():
        ax.plot(ks, recall, marker="o", markersize=3, label=label)
    ax.xaxis.get_major_locator().set_params(integer=True)  # psi counts neighbours
    ax.set_ylim(0, 1.02)
    return _finish(fig, ax, path, title or "recall", xlabel, ylabel, "lower right")


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
