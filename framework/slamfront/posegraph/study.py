"""The outlier study: how each robust option copes with false loop closures.

For each graph and outlier rate, random false loop closures are added
(:func:`~slamfront.core.posegraph.random_false_closures`: the rate is the share of all
loop closures that are false) and the graph is optimised with every method. Reported per
run: the ATE against ground truth (when given), the deviation from the clean solution
(the outlier-free graph optimised without a kernel), the cost of the *true* edges at the
solution (comparable across methods, unlike each method's own robust objective),
iterations and time.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from slamfront.core.alignment import ate_rmse
from slamfront.core.posegraph import PoseGraph, random_false_closures
from slamfront.outputs import make_folder, write_atomically
from slamfront.posegraph.io import read_graph, read_ground_truth
from slamfront.posegraph.kernels import METHODS, RATES
from slamfront.posegraph.solver import SolverOptions, objective, optimize
from slamfront.report.plots import _pyplot, save_figure


@dataclass
class StudyRow:
    """One optimisation of the study."""

    graph: str
    rate: float
    n_false: int
    method: str
    ate_m: float | None
    deviation_m: float
    """RMSE of positions from the clean solution after rigid alignment."""
    true_edge_cost: float
    """Half the sum of squared whitened residuals of the graph's true edges at the solution."""
    cost: float
    """The method's own objective at the solution (not comparable across methods)."""
    iterations: int
    seconds: float
    converged: bool
    false_kept: int | None = None
    """GNC only: false closures it kept as inliers."""
    true_rejected: int | None = None
    """GNC only: true loop closures it rejected."""


@dataclass
class StudyGraph:
    """A graph of the study, with its ground truth (or None)."""

    name: str
    graph: PoseGraph
    ground_truth: np.ndarray | None


def load(paths: Sequence[Path], ground_truths: Sequence[Path]) -> list[StudyGraph]:
    """Read the graphs and their ground truths (given in the same order, or none at all)."""
    graphs = []
    for k, path in enumerate(paths):
        graph = read_graph(path).parsed.graph
        truth = read_ground_truth(ground_truths[k], graph) if k < len(ground_truths) else None
        graphs.append(StudyGraph(Path(path).name, graph, truth))
    return graphs


def run_study(
    graphs: Sequence[StudyGraph],
    rates: Sequence[float] = RATES,
    methods: Sequence[str] = tuple(METHODS),
    seed: int = 0,
    progress: bool | None = None,
    on_row: Callable[[StudyRow], None] | None = None,
) -> list[StudyRow]:
    """Every (graph, rate, method) optimisation; the corrupted graphs are seeded."""
    rows: list[StudyRow] = []
    bar = tqdm(total=len(graphs) * len(rates) * len(methods), desc="outlier study", unit="run",
               disable=None if progress is None else not progress)
    for entry in graphs:
        clean = optimize(entry.graph, SolverOptions()).poses
        d = entry.graph.dim
        for k, rate in enumerate(rates):
            corrupted, false = random_false_closures(entry.graph, rate, np.random.default_rng([seed, k]))
            true_loops = ~false & ~corrupted.is_odometry()
            for method in methods:
                bar.set_postfix_str(f"{entry.name} {rate:.0%} {method}")
                result = optimize(corrupted, SolverOptions(**METHODS[method]))
                positions = result.poses[:, :d, d]
                weights = result.weights
                row = StudyRow(
                    graph=entry.name,
                    rate=rate,
                    n_false=int(false.sum()),
                    method=method,
                    ate_m=None if entry.ground_truth is None else ate_rmse(positions, entry.ground_truth),
                    deviation_m=ate_rmse(positions, clean[:, :d, d]),
                    true_edge_cost=objective(entry.graph, result.poses),
                    cost=result.cost_after,
                    iterations=result.iterations,
                    seconds=result.seconds,
                    converged=result.converged,
                    false_kept=None if weights is None else int(np.sum(weights[false] >= 0.5)),
                    true_rejected=None if weights is None else int(np.sum(weights[true_loops] < 0.5)),
                )
                rows.append(row)
                if on_row is not None:
                    on_row(row)
                bar.update()
    bar.close()
    return rows


def _clean_ate(rows: Sequence[StudyRow], graph: str) -> float | None:
    for row in rows:
        if row.graph == graph and row.rate == 0.0 and row.method == "none":
            return row.ate_m
    return None


def table(rows: Sequence[StudyRow]) -> str:
    """The study as one Markdown table."""
    lines = [
        "| graph | false closures | method | ATE [m] | ATE / clean | deviation from clean [m] | true-edge cost "
        "| iterations | time [s] | GNC: false kept / true rejected |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        clean = _clean_ate(rows, row.graph)
        ratio = f"{row.ate_m / clean:.3f}" if row.ate_m is not None and clean else "-"
        ate = f"{row.ate_m:.4g}" if row.ate_m is not None else "-"
        gnc = f"{row.false_kept} / {row.true_rejected}" if row.false_kept is not None else "-"
        flag = "" if row.converged else " (not converged)"
        lines.append(
            f"| {row.graph} | {row.rate:.0%} ({row.n_false}) | {row.method} | {ate} | {ratio} | "
            f"{row.deviation_m:.4g} | {row.true_edge_cost:.5g} | {row.iterations}{flag} | {row.seconds:.3g} | {gnc} |"
        )
    return "\n".join(lines)


def plot(rows: Sequence[StudyRow], path: Path) -> Path:
    """ATE (or deviation from the clean solution) against the outlier rate, per method and graph."""
    plt = _pyplot()
    graphs = list(dict.fromkeys(row.graph for row in rows))
    fig, axes = plt.subplots(1, len(graphs), figsize=(5.5 * len(graphs), 4.5), dpi=110, squeeze=False)
    for ax, graph in zip(axes[0], graphs):
        mine = [row for row in rows if row.graph == graph]
        use_ate = all(row.ate_m is not None for row in mine)
        for k, method in enumerate(dict.fromkeys(row.method for row in mine)):
            points = sorted((row.rate, row.ate_m if use_ate else row.deviation_m) for row in mine if row.method == method)
            # methods that all keep the clean ATE overlap: distinct markers keep each visible
            ax.plot([100 * p[0] for p in points], [max(p[1], 1e-4) for p in points], marker="osD^vP*X"[k % 8],
                    markersize=9 - k, linewidth=1.2, alpha=0.85, label=method)
        clean = _clean_ate(rows, graph) if use_ate else None
        if clean:
            ax.axhline(1.1 * clean, color="0.4", linestyle="--", linewidth=0.8, label="clean ATE + 10 %")
        ax.set_yscale("log")
        ax.set_xlabel("false loop closures [% of all loop closures]")
        ax.set_ylabel("ATE [m]" if use_ate else "deviation from clean solution [m]")
        ax.set_title(graph)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def write(rows: Sequence[StudyRow], out_dir: Path, plots: bool = True) -> list[Path]:
    """``outliers.md`` (table), ``outliers.json`` (rows) and ``outliers.png`` in ``out_dir``."""
    make_folder(out_dir)
    files = [
        write_atomically(out_dir / "outliers.md", "# Outlier study\n\n" + table(rows) + "\n"),
        write_atomically(out_dir / "outliers.json", json.dumps([asdict(r) for r in rows], indent=1) + "\n"),
    ]
    if plots and rows:
        files.append(plot(rows, out_dir / "outliers.png"))
    return files
