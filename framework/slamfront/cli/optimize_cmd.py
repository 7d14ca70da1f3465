"""``slamfront optimize GRAPH.g2o|LOG.mcap [--kernel NAME] [--ground-truth FILE] [-o DIR]``"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from slamfront.errors import SlamfrontError
from slamfront.posegraph.kernels import KERNELS, KernelName

if TYPE_CHECKING:
    from slamfront.posegraph.solver import SolverOptions


def add_parser(commands: argparse._SubParsersAction) -> None:
    kernels = ", ".join(f"{name} ({kernel.summary}; default {kernel.default_parameter})" for name, kernel in KERNELS.items())
    parser = commands.add_parser(
        "optimize",
        help="optimise a pose graph (g2o, iSAM, or a run log) with GTSAM",
        description=(
            "Optimise a pose graph with GTSAM and write DIR/metrics.json (cost_before, cost_after, iterations, "
            "seconds, and ate_rmse_before_m / ate_rmse_after_m with ground truth), DIR/optimized.g2o, "
            "DIR/trajectory.tum, DIR/report.md and DIR/before_after.svg. "
            f"Kernels: none, gnc (graduated non-convexity), {kernels}."
        ),
    )
    parser.add_argument("graph", type=Path, help="a g2o or iSAM file, or a run.mcap with a back end's pose graph")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: logs/optimize/<graph name>/)")
    parser.add_argument("--format", dest="graph_format", choices=("auto", "g2o", "isam"), default="auto",
                        help="graph file format (auto: from its record names)")
    parser.add_argument("--kernel", choices=get_args(KernelName), default="none", help="robust kernel on loop closures")
    parser.add_argument("--kernel-parameter", type=float, help="the kernel's threshold (default per kernel)")
    parser.add_argument("--robust-odometry", action="store_true", help="apply the kernel to odometry edges too")
    parser.add_argument("--mode", choices=("batch", "isam2"), default="batch",
                        help="batch Levenberg-Marquardt, or iSAM2 adding one vertex at a time")
    parser.add_argument("--isam2-factorization", choices=("auto", "cholesky", "qr"), default="auto",
                        help="iSAM2's linear solver (auto: Cholesky, redone with QR if the system is indeterminate)")
    parser.add_argument("--gnc-loss", choices=("tls", "gm"), default="tls", help="GNC surrogate loss")
    parser.add_argument("--gnc-warm-start", choices=("none", "dcs"), default="dcs",
                        help="start GNC from the initial poses or from a DCS solution")
    parser.add_argument("--max-iterations", type=int, default=100, help="Levenberg-Marquardt iteration limit")
    parser.add_argument("--ground-truth", type=Path, metavar="FILE",
                        help="true poses: TUM or 'x y theta' lines, or a noise-free graph (odometry is composed)")
    parser.add_argument("--no-plots", action="store_true", help="skip before_after.svg")
    parser.set_defaults(handler=run)


def options_from(args: argparse.Namespace) -> SolverOptions:
    """The solver options the flags describe (invalid combinations are user errors)."""
    from slamfront.posegraph.solver import InvalidOption, SolverOptions

    try:
        return SolverOptions(
            mode=args.mode, kernel=args.kernel, kernel_parameter=args.kernel_parameter,
            robust_odometry=args.robust_odometry, gnc_loss=args.gnc_loss, gnc_warm_start=args.gnc_warm_start,
            max_iterations=args.max_iterations, isam2_factorization=args.isam2_factorization,
        )
    except InvalidOption as exc:
        raise SlamfrontError(f"--{exc.field.replace('_', '-')}: {exc.problem}") from None
    except ValueError as exc:
        raise SlamfrontError(f"options: {exc}") from None


def run(args: argparse.Namespace) -> int:
    from slamfront.posegraph.workflow import PlotFailed, optimize_file

    options = options_from(args)
    out_dir = args.out or Path("logs") / "optimize" / args.graph.stem
    try:
        outcome = optimize_file(args.graph, out_dir, options, args.ground_truth, args.graph_format, not args.no_plots)
    except PlotFailed as failure:  # the results are written: show them, then fail
        outcome = failure.run
    metrics = outcome.metrics
    print(f"graph:   {args.graph} ({metrics['format']}, {metrics['dim']}-D, {metrics['n_vertices']} vertices, "
          f"{metrics['n_edges']} edges)")
    if metrics["skipped_records"]:
        skipped = ", ".join(f"{n} {tag}" for tag, n in metrics["skipped_records"].items())
        print(f"skipped: {skipped} (landmark records; this is a pose-graph optimiser)")
    print(f"cost:    {metrics['cost_before']:.6g} -> {metrics['cost_after']:.6g} in {metrics['iterations']} "
          f"{'updates' if options.mode == 'isam2' else 'iterations'}, {metrics['seconds']:.3g} s"
          f"{'' if metrics['converged'] else ' (NOT converged)'}")
    if "ate_rmse_after_m" in metrics:
        print(f"ATE:     {metrics['ate_rmse_before_m']:.4g} m -> {metrics['ate_rmse_after_m']:.4g} m")
    print(f"report:  {out_dir / 'report.md'}")
    print(f"metrics: {out_dir / 'metrics.json'}")
    if "plot_failed" in metrics:
        print(f"slamfront: error: {metrics['plot_failed']} (every other output is written)", file=sys.stderr)
        return 1
    return 0
