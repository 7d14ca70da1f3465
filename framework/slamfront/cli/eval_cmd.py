"""``slamfront eval traj GROUND_TRUTH ESTIMATE`` and ``slamfront eval descriptors SOURCE``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.errors import DataError
from slamfront.outputs import make_folder

if TYPE_CHECKING:
    from slamfront.core.trajectory import TrajectoryEvaluation
    from slamfront.formats.poses import Trajectory

TIMED_FORMATS = ("tum",)
FORMATS = ("kitti", "pose_lines", "redwood_log", "tum")
"""The names of :data:`slamfront.formats.poses.TRAJECTORY_READERS` (listed here so that
``--help`` does not import the readers; a test keeps the two equal)."""


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "eval",
        help="evaluate outside a run: trajectories (ATE/RPE), local descriptors (Barbosa 2017 ch. 5.1)",
        description="Evaluation tools that work on files, outside a recipe run.",
    )
    tools = parser.add_subparsers(dest="tool", metavar="TOOL", required=True, help="the evaluation to run")
    traj = tools.add_parser(
        "traj",
        help="ATE and RPE of an estimated trajectory against the ground truth",
        description=(
            "ATE (after Horn/Umeyama alignment) and RPE (translation and rotation) of ESTIMATE against "
            "GROUND_TRUTH, as the TUM RGB-D benchmark defines them; the same functions runs use. TUM files "
            "are associated by timestamp; the other formats pose by pose."
        ),
    )
    traj.add_argument("ground_truth", type=Path, metavar="GROUND_TRUTH", help="the ground-truth trajectory file")
    traj.add_argument("estimate", type=Path, metavar="ESTIMATE", help="the estimated trajectory file")
    traj.add_argument("--format", choices=FORMATS, default="tum", help="file format (default tum)")
    traj.add_argument("--align", choices=("se3", "sim3", "none"), default="se3",
                      help="alignment before ATE: rigid (default), with scale (monocular), or none")
    traj.add_argument("--delta", type=float, default=1,
                      help="RPE interval (default 1); every pair that far apart, as evo_rpe --all_pairs")
    traj.add_argument("--delta-unit", choices=("frames", "seconds"), default="frames", help="unit of --delta")
    traj.add_argument("--all-intervals", action="store_true",
                      help="also RPE over every interval (Sturm et al. 2012's average, as Barbosa 2017's table 6)")
    traj.add_argument("--max-difference", type=float, default=0.01, metavar="S",
                      help="TUM: largest timestamp difference to associate two poses "
                      "(default 0.01 s, evo's; the TUM benchmark's associate.py uses 0.02)")
    traj.add_argument("--offset", type=float, default=0.0, metavar="S", help="TUM: added to the estimate's timestamps")
    traj.add_argument("--repeated", choices=("first", "last"), metavar="{first,last}",
                      help="TUM: keep the first (or last) pose of each repeated timestamp and sort by time "
                      "(default: a file whose timestamps repeat or go back is refused)")
    traj.add_argument("--plot", type=Path, metavar="PNG", help="also draw ground truth and aligned estimate (top view)")
    traj.add_argument("--json", action="store_true", help="print the metrics as JSON")
    traj.set_defaults(handler=run_traj)
    from slamfront.cli import descriptor_eval_cmd

    descriptor_eval_cmd.add_parser(tools)


def load_and_evaluate(args: argparse.Namespace) -> tuple[Trajectory, Trajectory, TrajectoryEvaluation]:
    """Read both files and compute ATE/RPE, naming the files in any error."""
    from slamfront.core.errors import CoreError
    from slamfront.core.trajectory import evaluate_poses, evaluate_trajectories
    from slamfront.formats.poses import TRAJECTORY_READERS, in_time_order

    read = TRAJECTORY_READERS[args.format]
    gt, est = read(args.ground_truth), read(args.estimate)
    if args.format in TIMED_FORMATS:
        gt = in_time_order(gt, args.ground_truth, args.repeated)
        est = in_time_order(est, args.estimate, args.repeated)
    try:
        if args.format in TIMED_FORMATS:
            result = evaluate_trajectories(
                gt.timestamps, gt.poses, est.timestamps, est.poses, args.max_difference, args.offset,
                args.align, args.delta, args.delta_unit, args.all_intervals,
            )
        else:
            if len(gt) != len(est):
                raise DataError(
                    f"{args.estimate}: {len(est)} poses but {args.ground_truth} has {len(gt)}; "
                    f"{args.format} files carry no timestamps, so they are compared pose by pose"
                )
            result = evaluate_poses(gt.poses, est.poses, gt.timestamps, args.align, args.delta, args.delta_unit,
                                    all_intervals=args.all_intervals)
    except CoreError as exc:
        raise DataError(f"{args.estimate} vs {args.ground_truth}: {exc}") from None
    return gt, est, result


def run_traj(args: argparse.Namespace) -> int:
    import numpy as np

    gt, est, result = load_and_evaluate(args)
    metrics = result.metrics()
    if args.plot is not None:
        from slamfront.report import plots

        aligned = result.ate.alignment.apply_to_poses(est.poses[result.pairs[:, 1]])
        make_folder(args.plot.parent, "folder of the plot")
        try:
            plots.trajectories_2d(
                {"ground truth": gt.positions[result.pairs[:, 0]], f"estimate ({args.align} aligned)": aligned[:, :3, 3]},
                args.plot, f"ATE RMSE {metrics['ate_rmse_m']:.4g} m",
            )
        except OSError as exc:
            raise DataError(f"{args.plot}: cannot write the plot: {exc.strerror or exc}") from None
    if args.json:
        document = {"ground_truth": str(args.ground_truth), "estimate": str(args.estimate), **metrics}
        finite = {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in document.items()}
        print(json.dumps(finite, indent=2, allow_nan=False, default=_plain))
        return 0
    a, t, r = result.ate.statistics, result.rpe.translation_statistics, result.rpe.rotation_statistics
    print(f"ground truth: {args.ground_truth} ({len(gt)} poses)")
    print(f"estimate:     {args.estimate} ({len(est)} poses)")
    print(f"associated:   {len(result.pairs)} pose pairs")
    print(f"ATE ({args.align} alignment{f', scale {result.ate.alignment.scale:.4g}' if args.align == 'sim3' else ''}):"
          f" rmse {a.rmse:.6g} m, mean {a.mean:.6g}, median {a.median:.6g}, max {a.max:.6g}")
    print(f"RPE (delta {args.delta:g} {args.delta_unit}, {t.n} pairs): rmse {t.rmse:.6g} m, max {t.max:.6g} m, "
          f"rotation rmse {r.rmse:.6g} deg")
    if result.all_intervals is not None:
        every = result.all_intervals
        print(f"RPE (all {every.n_pairs} intervals, mean of per-interval RMSE): rmse {every.rmse:.6g} m, "
              f"max {every.max:.6g} m")
    print(f"ate_rmse_m = {a.rmse:.6g}")
    print(f"rpe_rmse_m = {t.rmse:.6g}")
    if result.all_intervals is not None:
        print(f"rpe_all_intervals_rmse_m = {result.all_intervals.rmse:.6g}")
    return 0


def _plain(value: object) -> object:
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(type(value).__name__)
