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
    return _save_top_view(plt, fig, ax, (a, b), title or "trajectory", path)


def _save_top_view(plt: Any, fig: Any, ax: Any, axes: tuple[int, int], title: str, path: Path) -> Path:
    """Equal-aspect metric axes, grid, legend; write the PNG and close the figure."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("xyz"[axes[0]] + " [m]")
    ax.set_ylabel("xyz"[axes[1]] + " [m]")
    ax.set_title(title)
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


def _top_view_axes(points: np.ndarray) -> tuple[int, int]:
    """The two axes a path spreads in most: (x, y), or (x, z) for y-down camera conventions."""
    spread = np.ptp(points, axis=0) if len(points) else np.ones(3)
    return (0, 1) if spread[1] >= spread[2] else (0, 2)


def localization_plot(
    truth: np.ndarray, estimate: np.ndarray, keyframes: np.ndarray, path: Path, title: str = ""
) -> Path:
    """Top view of ground-truth vs estimated positions, each pair joined, keyframes marked.

    :param truth: (N, 3) true positions, in route order.
    :param estimate: (N, 3) estimated positions of the same frames.
    :param keyframes: (K, 3) keyframe positions.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5.5), dpi=110)
    a, b = _top_view_axes(np.concatenate([truth, estimate, keyframes.reshape(-1, 3)]))
    for t, e in zip(truth, estimate):
        ax.plot([t[a], e[a]], [t[b], e[b]], color="tab:red", linewidth=0.5, alpha=0.5)
    ax.plot(truth[:, a], truth[:, b], color="tab:gray", linewidth=1.2, label="ground truth")
    ax.scatter(estimate[:, a], estimate[:, b], s=7, color="tab:blue", label="estimated", zorder=3)
    if len(keyframes):
        ax.scatter(keyframes[:, a], keyframes[:, b], s=40, marker="^", facecolors="none", edgecolors="tab:green",
                   label=f"keyframes ({len(keyframes)})", zorder=4)
    return _save_top_view(plt, fig, ax, (a, b), title or "localization", path)


def error_along(x: np.ndarray, errors: np.ndarray, path: Path, title: str = "", xlabel: str = "", ylabel: str = "") -> Path:
    """Per-frame errors (N,) against a position along the run (N,), with their RMSE as a line."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 3.2), dpi=110)
    order = np.argsort(x, kind="stable")
    ax.plot(x[order], errors[order], linewidth=0.8, marker=".", markersize=3)
    if len(errors):
        rmse = float(np.sqrt(np.mean(np.square(errors))))
        ax.axhline(rmse, color="tab:red", linewidth=0.8, linestyle="--", label=f"RMSE {rmse:.3g}")
        ax.legend(fontsize=8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def local_test(offsets: np.ndarray, curves: Mapping[str, Mapping[int, np.ndarray]], path: Path, title: str = "") -> Path:
    """Matches against neighbouring frames, one panel per target frame, one curve per descriptor.

    :param offsets: (M,) frame offsets from the target.
    :param curves: ``{descriptor: {target: (M,) matches (NaN: none)}}``.
    """
    plt = _pyplot()
    targets = sorted({t for per_target in curves.values() for t in per_target})
    fig, axes = _panels(plt, len(targets), 2, (5.2, 3.2))
    for ax, target in zip(axes.ravel(), targets):
        for label, per_target in curves.items():
            if target in per_target:
                ax.plot(offsets, per_target[target], marker="o", markersize=3, linewidth=1, label=label)
        ax.axvline(0, color="gray", linewidth=0.6, linestyle=":")
        ax.set_title(f"target frame {target}", fontsize=9)
        ax.set_xlabel("frame offset from target")
        ax.set_ylabel("matches after RANSAC")
        ax.grid(alpha=0.3)
    return _save_panels(plt, fig, axes, len(targets), title or "local test", path)


def _panels(plt: Any, count: int, columns: int, size: tuple[float, float]) -> tuple[Any, np.ndarray]:
    """A grid of at least ``count`` panels, ``columns`` wide at most."""
    columns = min(count, columns) or 1
    rows = max(1, int(np.ceil(count / columns)))
    return plt.subplots(rows, columns, figsize=(size[0] * columns, size[1] * rows), dpi=100, squeeze=False)


def _save_panels(plt: Any, fig: Any, axes: np.ndarray, used: int, title: str, path: Path) -> Path:
    """Blank the unused panels, put the legend in the first, write the PNG and close the figure."""
    for ax in axes.ravel()[used:]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle(title)
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


def distance_histograms(
    samples: Mapping[str, tuple[np.ndarray, np.ndarray, float]], path: Path, title: str = ""
) -> Path:
    """Per descriptor: distances of verified matches vs nearest neighbours in unrelated frames.

    :param samples: ``{descriptor: (verified distances, unrelated distances, threshold)}``.
    """
    plt = _pyplot()
    labels = list(samples)
    fig, axes = _panels(plt, len(labels), 3, (4.2, 3.0))
    for ax, label in zip(axes.ravel(), labels):
        verified, unrelated, threshold = samples[label]
        both = np.concatenate([verified, unrelated]) if len(verified) + len(unrelated) else np.zeros(1)
        bins = np.linspace(0, float(np.max(both)) * 1.02 + 1e-9, 40)
        if len(unrelated):
            ax.hist(unrelated, bins=bins, alpha=0.5, density=True, color="tab:red", label="nearest, unrelated frames")
        if len(verified):
            ax.hist(verified, bins=bins, alpha=0.5, density=True, color="tab:green", label="verified, neighbouring frames")
        ax.axvline(threshold, color="black", linewidth=1, linestyle="--", label=f"threshold {threshold:g}")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("descriptor distance")
    return _save_panels(plt, fig, axes, len(labels), title or "match distances", path)


def localization_pr(
    recall: np.ndarray, precision: np.ndarray, operating: tuple[float, float], recall_at_100p: float, path: Path,
    title: str = "",
) -> Path:
    """A localizer's precision-recall curve over its confidence, with its operating point marked.

    :param recall: (T,) recall at each confidence threshold, thresholds decreasing.
    :param precision: (T,) precision at the same thresholds.
    :param operating: (recall, precision) of the answers the localizer gave.
    :param recall_at_100p: the largest recall with no wrong answer (drawn as a dotted line).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    ax.step(np.r_[0.0, recall], np.r_[1.0, precision], where="post", label="confidence swept")
    ax.axvline(recall_at_100p, color="tab:green", linestyle=":", linewidth=1,
               label=f"recall@100%P = {recall_at_100p:.3f}")
    ax.scatter([operating[0]], [operating[1]], color="tab:red", zorder=3,
               label=f"answers given (P {operating[1]:.3f}, R {operating[0]:.3f})")
    ax.set_xlim(0, 1.0)
    ax.set_ylim(0, 1.02)
    return _finish(fig, ax, path, title or "localization precision-recall", "recall (in-map frames)",
                   "precision", "lower left")
