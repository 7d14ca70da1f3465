"""``slamfront optimize`` as a library call: read, optimise, measure, write.

Outputs in the chosen folder: ``metrics.json``, ``optimized.g2o`` (the graph with the
optimised poses as vertices), ``trajectory.tum`` and ``initial.tum`` (timestamps are the
frames' times when the input is a run log, else vertex ids), ``report.md`` and
``before_after.svg``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slamfront.core.alignment import ate_rmse
from slamfront.core.graph_files import GraphFormat
from slamfront.core.posegraph import PoseGraph
from slamfront.outputs import folder_lock, write_atomically
from slamfront.posegraph import report
from slamfront.posegraph.io import read_graph, read_ground_truth, write_g2o, write_tum
from slamfront.posegraph.solver import OptimizationResult, SolverOptions, optimize
from slamfront.report.metrics_file import write_json_atomically

SHOWN = (
    "graph", "format", "dim", "n_vertices", "n_edges", "n_loop_closures", "mode", "kernel", "kernel_parameter",
    "cost_before", "cost_after", "iterations", "seconds", "converged", "ate_rmse_before_m", "ate_rmse_after_m",
    "n_rejected_edges", "ground_truth",
)
"""The metrics ``report.md`` lists, in order."""


@dataclass
class OptimizeRun:
    """What ``slamfront optimize`` produced."""

    out_dir: Path
    metrics: dict[str, Any]
    result: OptimizationResult
    files: list[Path]


class PlotFailed(Exception):
    """The plot failed; every other output was written (``run``), and the report and
    metrics say so (an older run's plot is removed)."""

    def __init__(self, message: str, run: OptimizeRun) -> None:
        super().__init__(message)
        self.run = run


def optimize_file(
    graph_path: Path,
    out_dir: Path,
    options: SolverOptions | None = None,
    ground_truth: Path | None = None,
    graph_format: GraphFormat = "auto",
    plots: bool = True,
) -> OptimizeRun:
    """Optimise a graph file (or a run log's graph) and write the results to ``out_dir``.

    :param ground_truth: a trajectory or noise-free graph (see
        :func:`~slamfront.posegraph.io.read_ground_truth`); a run log brings its own.
    :raises DataError: unreadable or invalid inputs (nothing is written then).
    """
    options = options or SolverOptions()
    loaded = read_graph(graph_path, graph_format)
    graph = loaded.parsed.graph
    truth = read_ground_truth(ground_truth, graph) if ground_truth is not None else loaded.ground_truth
    result = optimize(graph, options, Path(graph_path) if loaded.parsed.plain_g2o else None)
    d = graph.dim
    metrics: dict[str, Any] = {
        "graph": str(graph_path),
        "format": loaded.parsed.format,
        "dim": d,
        "n_vertices": graph.n_vertices,
        "n_edges": graph.n_edges,
        "n_loop_closures": int(np.sum(~graph.is_odometry())),
        "skipped_records": loaded.parsed.skipped,
        "kernel_parameter": options.parameter() if options.kernel not in ("none", "gnc") else None,
        **result.summary(),
    }
    if truth is not None:
        metrics["ate_rmse_before_m"] = ate_rmse(result.initial[:, :d, d], truth)
        metrics["ate_rmse_after_m"] = ate_rmse(result.poses[:, :d, d], truth)
        metrics["ground_truth"] = str(ground_truth) if ground_truth is not None else "from the log"

    # one optimize at a time per folder: two writing the same files would leave a mix of both
    with folder_lock(out_dir, "optimize"):
        files = [
            write_g2o(out_dir / "optimized.g2o", graph, result.poses),
            write_tum(out_dir / "trajectory.tum", graph, result.poses, loaded.timestamps),
            write_tum(out_dir / "initial.tum", graph, result.initial, loaded.timestamps),
        ]
        figures, plot_failure = [], ""
        if not plots:  # an older run's plot must not sit beside these results
            with contextlib.suppress(OSError):
                (out_dir / "before_after.svg").unlink(missing_ok=True)
        else:
            try:
                figures.append(_plot(out_dir / "before_after.svg", graph_path, graph, result, truth, options))
            except Exception as exc:  # noqa: BLE001 - the results stand; the failure is reported, never hidden
                plot_failure = f"before_after.svg: the plot failed: {type(exc).__name__}: {exc}"
                metrics["plot_failed"] = plot_failure
                with contextlib.suppress(OSError):  # an older run's plot must not sit beside these results
                    (out_dir / "before_after.svg").unlink(missing_ok=True)
        files += figures
        markdown = [
            f"# Pose-graph optimisation: {Path(graph_path).name}",
            "",
            report.metrics_table(metrics, SHOWN),
            "",
            "Cost is GTSAM's objective: half the sum of squared whitened residuals (through the kernel).",
            "ATE: RMSE of vertex positions after a rigid alignment to the ground truth.",
            "",
            *(f"![{f.name}]({f.name})\n" for f in figures),
            *([f"**The plot failed**: {plot_failure}\n"] if plot_failure else []),
        ]
        files.append(write_atomically(out_dir / "report.md", "\n".join(markdown) + "\n"))
        files.append(write_json_atomically(out_dir / "metrics.json", metrics))
    run = OptimizeRun(out_dir, metrics, result, files)
    if plot_failure:
        raise PlotFailed(plot_failure, run)
    return run


def _plot(
    path: Path, graph_path: Path, graph: PoseGraph, result: OptimizationResult, truth: np.ndarray | None,
    options: SolverOptions,
) -> Path:
    d = graph.dim
    loops = np.flatnonzero(~graph.is_odometry())
    return report.before_after(
        {
            f"initial (cost {result.cost_before:.4g})": result.initial[:, :d, d],
            f"optimised (cost {result.cost_after:.4g}, {result.iterations} iterations)": result.poses[:, :d, d],
        },
        path,
        ground_truth=truth,
        loops=np.stack([graph.index_of(graph.sources[loops]), graph.index_of(graph.targets[loops])], axis=1),
        title=f"{Path(graph_path).name}: {options.mode}, kernel {options.kernel}",
    )
