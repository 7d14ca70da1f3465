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


def save_figure(fig: Any, path: Path) -> None:
    """Save a figure without following a link planted at ``path`` (written beside it, renamed onto it)."""
    import io

    from slamfront.outputs import write_atomically

    buffer = io.BytesIO()
    fig.savefig(buffer, format=Path(path).suffix.lstrip(".").lower() or "png")
    write_atomically(Path(path), buffer.getvalue())


def _finish(fig: Any, ax: Any, path: Path, title: str, xlabel: str, ylabel: str, legend: str) -> Path:
    """Labels, grid, legend; save and close."""
    plt = _pyplot()
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc=legend, fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


OPERATING_POINT_MARKERS = ("o", "*", "D", "s", "^", "v")
"""Marker of the 1st, 2nd, ... operating point drawn on a precision-recall plot."""


def pr_curves(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "",
    points: Mapping[str, tuple[float, float]] | None = None,
) -> Path:
    """Precision-recall curves, one per label: ``{label: (recall, precision)}``.

    :param points: operating points to mark, ``{label: (recall, precision)}``: where a
        detector's own threshold puts it on its curve, or what survives verification.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    for label, (recall, precision) in curves.items():
        ax.step(np.r_[0.0, recall], np.r_[1.0, precision], where="post", label=label)
    for k, (label, (recall, precision)) in enumerate((points or {}).items()):
        marker = OPERATING_POINT_MARKERS[k % len(OPERATING_POINT_MARKERS)]
        ax.plot([recall], [precision], linestyle="none", marker=marker, markersize=9, markeredgecolor="black",
                color=f"C{k + len(curves)}", zorder=5, label=f"{label}: P {precision:.2f}, R {recall:.2f}")
    ax.set_xlim(0, 1.0)
    ax.set_ylim(0, 1.05)
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
    accepted: np.ndarray | None = None,
) -> Path:
    """Chosen reference vs query over the ground-truth band, coloured by confidence.

    Dots are correct matches, crosses wrong ones; filled markers were accepted by the
    detector, hollow (or thin) ones rejected. The colour scale spans the confidences
    the detector gave, so their differences stay visible whatever its range.

    :param query: (N,) x positions; ``match`` (N,) y positions (NaN for no answer).
    :param truth_lo: (N,) / ``truth_hi`` (N,) the band of correct matches (NaN: none).
    :param accepted: (N,) bool, the detector's decision (None: all accepted).
    """
    from matplotlib.colors import Normalize

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5), dpi=110)
    order = np.argsort(query)
    ax.fill_between(
        query[order], truth_lo[order], truth_hi[order], color="tab:green", alpha=0.25, step="mid",
        label="ground truth (within tolerance)", linewidth=0,
    )
    answered = np.isfinite(match)
    accepted = np.ones(len(query), dtype=bool) if accepted is None else np.asarray(accepted, dtype=bool)
    shown = confidence[answered & np.isfinite(confidence)]
    low, high = (float(shown.min()), float(shown.max())) if len(shown) else (0.0, 1.0)
    if high - low < 1e-9:  # one confidence for all: a band around it
        low, high = low - 0.05, high + 0.05
    norm, cmap = Normalize(low, high), plt.get_cmap("viridis")
    colour = cmap(norm(np.nan_to_num(confidence, nan=low)))
    styles = (  # (mask, marker, size, filled, label)
        (answered & correct & accepted, "o", 14, True, "correct, accepted"),
        (answered & correct & ~accepted, "o", 14, False, "correct, rejected"),
        (answered & ~correct & accepted, "X", 40, True, "wrong, accepted"),
        (answered & ~correct & ~accepted, "x", 18, False, "wrong, rejected"),
    )
    for mask, marker, size, filled, label in styles:
        if not mask.any():
            continue
        if filled:
            ax.scatter(query[mask], match[mask], c=colour[mask], marker=marker, s=size,
                       edgecolors="black" if marker == "X" else "none", linewidths=0.4, label=label)
        elif marker == "o":
            ax.scatter(query[mask], match[mask], facecolors="none", edgecolors=colour[mask], marker=marker, s=size,
                       linewidths=0.8, label=label)
        else:
            ax.scatter(query[mask], match[mask], c=colour[mask], marker=marker, s=size, linewidths=0.6, alpha=0.6,
                       label=label)
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="confidence")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title or "matches")
    ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def trajectories_2d(
    paths: Mapping[str, np.ndarray], path: Path, title: str = "", markers: Sequence[np.ndarray] = (),
    links: Mapping[str, tuple[np.ndarray, str]] | None = None,
    flagged: Mapping[str, tuple[np.ndarray, str, str]] | None = None,
) -> Path:
    """Top view (x, y) of one or more trajectories: ``{label: (N, 3) positions}``.

    The plane is the one the trajectories spread in most (x-y, or x-z for camera
    conventions with y down).

    :param markers: (2, 3) segments drawn as thin red lines, unlabelled.
    :param links: labelled segments, ``{label: ((L, 2, 3) end points, colour)}``, e.g.
        loop closures (correct ones in one colour, wrong ones in another).
    :param flagged: labelled positions to mark, ``{label: ((K, 3) positions, marker, colour)}``,
        e.g. frames whose registration was rejected.
    """
    from matplotlib.collections import LineCollection

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
    for label, (segments, colour) in (links or {}).items():
        if len(segments):
            ax.add_collection(LineCollection(np.asarray(segments)[:, :, [a, b]], colors=colour, linewidths=0.8,
                                             alpha=0.7, label=f"{label} ({len(segments)})"))
    for label, (points, marker, colour) in (flagged or {}).items():
        if len(points):
            ax.scatter(points[:, a], points[:, b], marker=marker, color=colour, s=18, zorder=4, alpha=0.8,
                       linewidths=0, label=f"{label} ({len(points)})")
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
    save_figure(fig, path)
    plt.close(fig)
    return path


OUTCOME_COLOURS = {"aligned": "tab:blue", "fallback": "tab:orange", "rejected": "tab:red", "failed": "black"}
"""Colour of each registration outcome in the registration plots."""


def pair_errors(
    frames: np.ndarray, translation_m: np.ndarray, rotation_deg: np.ndarray, fitness: np.ndarray, path: Path,
    title: str = "", outcomes: Sequence[str] | None = None,
) -> Path:
    """Per-pair relative pose error (translation, rotation) and registration fitness by frame.

    Bars are coloured by ``outcomes`` (aligned, fallback, rejected: the frame's pose is a
    guess), and error spikes (beyond the median + 5 robust deviations) are circled and
    numbered with their frame.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), dpi=110, sharex=True)
    kinds = np.asarray(outcomes if outcomes is not None else ["aligned"] * len(frames))
    for ax, values, label, spikes in (
        (axes[0], translation_m * 100.0, "RPE translation [cm]", True),
        (axes[1], rotation_deg, "RPE rotation [deg]", True),
        (axes[2], fitness, "fitness", False),
    ):
        finite = np.isfinite(values)
        for outcome, colour in OUTCOME_COLOURS.items():
            chosen = finite & (kinds == outcome)
            if chosen.any():
                ax.bar(frames[chosen], values[chosen], color=colour, width=0.8, label=outcome)
        if spikes:
            _mark_spikes(ax, frames, values)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    axes[2].set_ylim(0, 1.02)
    axes[2].set_xlabel("frame")
    axes[0].legend(fontsize=7, ncols=4, loc="upper right")
    axes[0].set_title(title or "per-pair errors")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def spike_threshold(values: np.ndarray, deviations: float = 5.0) -> float:
    """Where an error counts as a spike: the median plus ``deviations`` robust standard
    deviations (1.4826 x the median absolute deviation) of the finite ``values``."""
    finite = values[np.isfinite(values)]
    if len(finite) < 3:
        return np.inf
    median = float(np.median(finite))
    spread = 1.4826 * float(np.median(np.abs(finite - median)))
    return median + deviations * max(spread, 1e-12)


def _mark_spikes(ax: Any, x: np.ndarray, values: np.ndarray, most: int = 8) -> int:
    """Circle the values above :func:`spike_threshold` and label the largest ``most`` with their x."""
    with np.errstate(invalid="ignore"):
        spikes = np.flatnonzero(values > spike_threshold(values))
    if not len(spikes):
        return 0
    ax.scatter(x[spikes], values[spikes], s=60, facecolors="none", edgecolors="tab:red", linewidths=1.2, zorder=5,
               label=f"spikes ({len(spikes)})")
    for k in spikes[np.argsort(values[spikes])[::-1][:most]]:
        ax.annotate(f"{int(x[k])}", (x[k], values[k]), textcoords="offset points", xytext=(3, 4), fontsize=7,
                    color="tab:red")
    return len(spikes)


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
    save_figure(fig, path)
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
    save_figure(fig, path)
    plt.close(fig)
    return path


def _top_view_axes(points: np.ndarray) -> tuple[int, int]:
    """The two axes a path spreads in most: (x, y), or (x, z) for y-down camera conventions."""
    spread = np.ptp(points, axis=0) if len(points) else np.ones(3)
    return (0, 1) if spread[1] >= spread[2] else (0, 2)


def localization_plot(
    truth: np.ndarray, estimate: np.ndarray, keyframes: np.ndarray, path: Path, title: str = "",
    lost: np.ndarray | None = None,
) -> Path:
    """Top view of ground-truth vs estimated positions, each pair joined, keyframes marked.

    Estimates whose error is a spike (:func:`spike_threshold`) are circled in red.

    :param truth: (N, 3) true positions, in route order.
    :param estimate: (N, 3) estimated positions of the same frames.
    :param keyframes: (K, 3) keyframe positions.
    :param lost: (M, 3) true positions of the frames that were not localized.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5.5), dpi=110)
    lost = np.zeros((0, 3)) if lost is None else np.asarray(lost).reshape(-1, 3)
    a, b = _top_view_axes(np.concatenate([truth, estimate, keyframes.reshape(-1, 3), lost]))
    for t, e in zip(truth, estimate):
        ax.plot([t[a], e[a]], [t[b], e[b]], color="tab:red", linewidth=0.5, alpha=0.5)
    ax.plot(truth[:, a], truth[:, b], color="tab:gray", linewidth=1.2, label="ground truth")
    ax.scatter(estimate[:, a], estimate[:, b], s=7, color="tab:blue", label="estimated", zorder=3)
    errors = np.linalg.norm(estimate - truth, axis=1)
    with np.errstate(invalid="ignore"):
        spikes = errors > spike_threshold(errors)
    if spikes.any():
        ax.scatter(estimate[spikes, a], estimate[spikes, b], s=60, facecolors="none", edgecolors="tab:red",
                   linewidths=1.2, zorder=5, label=f"error spikes ({int(spikes.sum())})")
    if len(keyframes):
        ax.scatter(keyframes[:, a], keyframes[:, b], s=40, marker="^", facecolors="none", edgecolors="tab:green",
                   label=f"keyframes ({len(keyframes)})", zorder=4)
    if len(lost):
        ax.scatter(lost[:, a], lost[:, b], s=25, marker="x", color="black", zorder=4,
                   label=f"not localized ({len(lost)})")
    return _save_top_view(plt, fig, ax, (a, b), title or "localization", path)


def error_along(
    x: np.ndarray, errors: np.ndarray, path: Path, title: str = "", xlabel: str = "", ylabel: str = "",
    missing: np.ndarray | None = None,
) -> Path:
    """Per-frame errors (N,) against a position along the run (N,), with their RMSE as a
    line, spikes (:func:`spike_threshold`) circled and labelled with their x, and the x of
    frames without an estimate (``missing``) ticked along the bottom."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 3.2), dpi=110)
    order = np.argsort(x, kind="stable")
    ax.plot(x[order], errors[order], linewidth=0.8, marker=".", markersize=3)
    if len(errors):
        rmse = float(np.sqrt(np.mean(np.square(errors))))
        ax.axhline(rmse, color="tab:red", linewidth=0.8, linestyle="--", label=f"RMSE {rmse:.3g}")
        _mark_spikes(ax, x, errors)
    if missing is not None and len(missing):
        ax.plot(missing, np.zeros(len(missing)), linestyle="none", marker="|", markersize=10, color="black",
                label=f"no estimate ({len(missing)})")
    if len(errors) or (missing is not None and len(missing)):
        ax.legend(fontsize=8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
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
    save_figure(fig, path)
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
    save_figure(fig, path)
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
