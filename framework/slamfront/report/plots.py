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


def pair_errors(
    frames: np.ndarray, translation_m: np.ndarray, rotation_deg: np.ndarray, fitness: np.ndarray, path: Path,
    title: str = "",
) -> Path:
    """Per-pair relative pose error (translation, rotation) and registration fitness by frame."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), dpi=110, sharex=True)
    for ax, values, label, colour in (
        (axes[0], translation_m * 100.0, "RPE translation [cm]", "tab:blue"),
        (axes[1], rotation_deg, "RPE rotation [deg]", "tab:orange"),
        (axes[2], fitness, "fitness", "tab:green"),
    ):
        finite = np.isfinite(values)
        ax.bar(frames[finite], values[finite], color=colour, width=0.8)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    axes[2].set_ylim(0, 1.02)
    axes[2].set_xlabel("frame")
    axes[0].set_title(title or "per-pair errors")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def stacked_seconds(frames: np.ndarray, steps: Mapping[str, np.ndarray], path: Path, title: str = "") -> Path:
    """Time per processing step for each frame, stacked: ``{step: (N,) seconds}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.8), dpi=110)
    bottom = np.zeros(len(frames))
    for label, seconds in steps.items():
        ax.bar(frames, seconds, bottom=bottom, label=label, width=0.8)
        bottom = bottom + seconds
    ax.set_xlabel("frame")
    ax.set_ylabel("seconds")
    ax.set_title(title or "time per step")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=7, ncols=min(len(steps), 4))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def cloud_top_view(
    points: np.ndarray, colors: np.ndarray | None, path: Path, title: str = "", max_points: int = 200_000,
    cameras: np.ndarray | None = None, up: np.ndarray | None = None,
) -> Path:
    """A point cloud seen from above, in its own colours.

    :param cameras: optional (M, 3) camera positions drawn as a path.
    :param up: the world's up direction (for cameras: minus their mean y axis, which
        points down); default: look along the axis the cloud spreads least in.
    """
    plt = _pyplot()
    points = np.asarray(points, dtype=np.float64)
    if len(points) > max_points:  # evenly thinned: a picture needs no more
        keep = np.linspace(0, len(points) - 1, max_points).astype(np.int64)
        points = points[keep]
        colors = None if colors is None else np.asarray(colors)[keep]
    if up is None or not np.linalg.norm(up) > 0:
        up = np.eye(3)[int(np.argmin(np.ptp(points, axis=0)))] if len(points) else np.array([0.0, 0.0, 1.0])
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    first = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    first /= np.linalg.norm(first)
    basis = np.stack([first, np.cross(up, first), up], axis=1)  # columns: right-handed plane axes, then up
    fig, ax = plt.subplots(figsize=(6, 5.5), dpi=120)
    if len(points):
        flat = points @ basis
        order = np.argsort(flat[:, 2])  # draw low to high so the top stays visible
        shown = None if colors is None else np.asarray(colors)[order] / 255.0
        ax.scatter(flat[order, 0], flat[order, 1], c=shown, s=0.3, linewidths=0)
        if cameras is not None and len(cameras):
            seen = np.asarray(cameras) @ basis
            ax.plot(seen[:, 0], seen[:, 1], color="tab:red", linewidth=1.0, marker=".", markersize=3, label="cameras")
            ax.legend(fontsize=8)
    ax.set_xlabel("[m]")
    ax.set_ylabel("[m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title or "model (top view)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
