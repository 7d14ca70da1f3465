"""A campaign's figures: each metric against each varied parameter, the methods side by
side, and the precision-recall curves of the runs (read from each run's ``pr_curve.csv``).

Repetitions are averaged (error bars: their standard deviation). Where a figure would
need more lines than it can show, the other parameters are collapsed to their best value
and the title says so; "best" is chosen on the campaign's own runs, so it is a tuned
upper bound, not a held-out result.
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slamfront.campaign.plan import format_value, short_name
from slamfront.campaign.results import ResultsTable
from slamfront.report import plots
from slamfront.report.plots import save_figure

MAX_LINES = 10
_LOWER_IS_BETTER = re.compile(r"(_m|_ms|_s|seconds|rmse|error|_bytes)$")

Row = dict[str, Any]


def higher_is_better(metric: str) -> bool:
    """Recall, precision, AUC: higher; errors, times, sizes: lower."""
    return _LOWER_IS_BETTER.search(metric) is None


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        return None
    return float(value)


def _best(values: Sequence[float], metric: str) -> float:
    return max(values) if higher_is_better(metric) else min(values)


def _score(row: Row, metric: str) -> float:
    """Larger is better whatever the metric's direction; missing is worst."""
    value = _number(row.get(metric))
    if value is None:
        return -np.inf
    return value if higher_is_better(metric) else -value


def _key(row: Row, columns: Sequence[str]) -> tuple[str, ...]:
    return tuple(format_value(row.get(c)) for c in columns)


def _legend(columns: Sequence[str], values: Sequence[str]) -> str:
    return " ".join(v if c == "method" else f"{short_name(c)}={v}" for c, v in zip(columns, values))


def _file_part(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.=+-]+", "_", text).strip("_") or "all"


def _finished(table: ResultsTable) -> list[Row]:
    return [row for row in table.rows if row["status"] == "ok"]


def _plotted_metrics(table: ResultsTable, rows: Sequence[Row]) -> list[str]:
    return [m for m in table.metric_columns if any(_number(r.get(m)) is not None for r in rows)]


def _line_points(
    rows: Sequence[Row], metric: str, param: str, line_columns: Sequence[str], collapsed: Sequence[str]
) -> dict[tuple[str, ...], dict[str, tuple[float, float]]]:
    """``{line: {x: (y, spread)}}``: y is the mean over repetitions, then the best over the
    collapsed columns; the spread is the repetitions' standard deviation (0 when collapsed)."""
    samples: dict[tuple, dict[str, dict[tuple, list[float]]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for row in rows:
        value = _number(row.get(metric))
        if value is not None:
            samples[_key(row, line_columns)][format_value(row.get(param))][_key(row, collapsed)].append(value)
    points: dict[tuple[str, ...], dict[str, tuple[float, float]]] = {}
    for line, by_x in samples.items():
        points[line] = {}
        for x, cells in by_x.items():
            if collapsed:
                points[line][x] = (_best([float(np.mean(v)) for v in cells.values()], metric), 0.0)
            else:
                (values,) = cells.values()
                points[line][x] = (float(np.mean(values)), float(np.std(values)))
    return points


def metric_vs_parameter(table: ResultsTable, out_dir: Path) -> list[Path]:
    """``vs_<param>.png`` for every parameter with two or more values: one panel per metric,
    one line per combination of the other factors."""
    rows = _finished(table)
    metrics = _plotted_metrics(table, rows)
    figures = []
    for param in table.param_columns:
        x_values = sorted({format_value(r.get(param)) for r in rows})
        if len(x_values) < 2 or not metrics:
            continue
        numeric = all(_number(r.get(param)) is not None for r in rows)
        others = ["method", *table.label_columns, *[p for p in table.param_columns if p != param]]
        too_many = len({_key(r, others) for r in rows}) > MAX_LINES
        collapsed = [p for p in table.param_columns if p != param] if too_many else []
        line_columns = [c for c in others if c not in collapsed]

        plt, fig, axes = _panels(len(metrics))
        for ax, metric in zip(axes, metrics):
            for line, by_x in sorted(_line_points(rows, metric, param, line_columns, collapsed).items()):
                xs = sorted(by_x, key=(lambda v: float(v)) if numeric else x_values.index)
                positions = [float(x) for x in xs] if numeric else [x_values.index(x) for x in xs]
                ys, spread = zip(*(by_x[x] for x in xs))
                ax.errorbar(positions, ys, yerr=spread if any(spread) else None, marker="o", ms=4, capsize=3,
                            label=_legend(line_columns, line))
            if not numeric:
                ax.set_xticks(range(len(x_values)), x_values, rotation=30, ha="right")
            ax.set_xlabel(short_name(param))
            ax.set_ylabel(metric)
            ax.grid(alpha=0.3)
        title = f"metrics vs {short_name(param)}"
        if collapsed:
            title += f" (each point: best over {', '.join(short_name(c) for c in collapsed)})"
        _finish(plt, fig, axes[0], title)
        path = out_dir / f"vs_{_file_part(short_name(param))}.png"
        save_figure(fig, path)
        plt.close(fig)
        figures.append(path)
    return figures


def methods_side_by_side(table: ResultsTable, out_dir: Path) -> list[Path]:
    """``methods.png``: each metric per method, grouped by the labels (best over parameters)."""
    rows = _finished(table)
    methods = sorted({r["method"] for r in rows})
    metrics = _plotted_metrics(table, rows)
    if len(methods) < 2 or not metrics:
        return []
    groups = sorted({_key(r, table.label_columns) for r in rows})
    plt, fig, axes = _panels(len(metrics), width=max(4.6, 0.5 * len(groups) * len(methods) + 1.5))
    bar = 0.8 / len(methods)
    for ax, metric in zip(axes, metrics):
        for m, method in enumerate(methods):
            heights = []
            for group in groups:
                members = [r for r in rows if r["method"] == method and _key(r, table.label_columns) == group]
                by_x = _line_points(members, metric, "method", [], table.param_columns)
                heights.append(by_x[()][format_value(method)][0] if by_x else np.nan)
            ax.bar(np.arange(len(groups)) + (m - (len(methods) - 1) / 2) * bar, heights, bar, label=method)
        ax.set_xticks(range(len(groups)), [" ".join(g) if any(g) else "all" for g in groups], rotation=20, ha="right")
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3, axis="y")
    suffix = " (best over the swept parameters)" if table.param_columns else ""
    _finish(plt, fig, axes[0], "methods side by side" + suffix)
    path = out_dir / "methods.png"
    save_figure(fig, path)
    plt.close(fig)
    return [path]


def pr_curves(table: ResultsTable, curves: Mapping[int, tuple[np.ndarray, np.ndarray]], out_dir: Path) -> list[Path]:
    """``pr.png`` (or ``pr_<labels>.png`` per variant/experiment): a curve per run, or per
    method its run with the best first metric when there are too many.

    :param curves: ``{row index: (recall, precision)}`` for the runs that have a curve.
    """
    groups: dict[tuple[str, ...], list[int]] = defaultdict(list)
    for index in sorted(curves):
        groups[_key(table.rows[index], table.label_columns)].append(index)
    primary = table.metric_columns[0] if table.metric_columns else None
    varied = [*table.param_columns, *(["repetition"] if table.repetitions else [])]
    figures = []
    for group, indices in sorted(groups.items()):
        chosen, note = indices, ""
        if len(indices) > MAX_LINES and primary is not None:
            by_method: dict[str, list[int]] = defaultdict(list)
            for i in indices:
                by_method[table.rows[i]["method"]].append(i)
            keep = max(1, MAX_LINES // len(by_method))
            chosen = sorted(i for members in by_method.values()
                            for i in sorted(members, key=lambda i: -_score(table.rows[i], primary))[:keep])
            note = f" (best {keep} by {primary} per method)"
        named = {_legend(["method", *varied], _key(table.rows[i], ["method", *varied])): curves[i] for i in chosen}
        title = (_legend(table.label_columns, group) or "precision-recall") + note
        name = f"pr_{_file_part('_'.join(group))}.png" if table.label_columns else "pr.png"
        figures.append(plots.pr_curves(named, out_dir / name, title=title))
    return figures


def _panels(n: int, width: float = 4.6, per_row: int = 3) -> tuple[Any, Any, list[Any]]:
    """pyplot, a figure and ``n`` axes in rows of ``per_row`` (spare axes hidden)."""
    plt = plots._pyplot()
    columns = min(n, per_row)
    rows = (n + columns - 1) // columns
    fig, grid = plt.subplots(rows, columns, figsize=(width * columns, 3.8 * rows + 0.6), dpi=110, squeeze=False)
    axes = list(grid.ravel())
    for spare in axes[n:]:
        spare.set_visible(False)
    return plt, fig, axes[:n]


def _finish(plt: Any, fig: Any, first_ax: Any, title: str) -> None:
    fig.suptitle(title)
    handles, labels = first_ax.get_legend_handles_labels()
    if len(labels) > 1:
        columns = min(3, len(labels))
        rows = (len(labels) + columns - 1) // columns
        fig.legend(handles, labels, loc="lower center", ncol=columns, fontsize=8)
        height = fig.get_size_inches()[1]
        fig.tight_layout(rect=(0, min(0.5, (0.22 * rows + 0.1) / height), 1, 1))
    else:
        fig.tight_layout()
