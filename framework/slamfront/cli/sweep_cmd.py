"""``slamfront sweep SWEEP [-o DIR] [--workers N] [--ray ADDRESS|auto|local]``"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.cli.arguments import frame_count

if TYPE_CHECKING:
    from slamfront.campaign.backends import Backend


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "sweep",
        help="run a campaign (parameter sweep, method comparison) from a sweep file",
        description=(
            "Run every run of a sweep file in parallel, skipping runs already finished in DIR "
            "(so the same command resumes an interrupted campaign). Writes DIR/results.csv, "
            "DIR/results.json, DIR/report.md and DIR/report.html (linking each run's report), plots, and DIR/runs/<run>/ with each run's log and metrics. "
            "Exit code: 0 all runs ok, 1 some failed (rerun to retry them), 130 interrupted, 2 bad sweep."
        ),
    )
    parser.add_argument("sweep", help="sweep file, or the name of a shipped sweep in sweeps/")
    parser.add_argument("-o", "--out", type=Path, help="campaign folder (default: logs/sweeps/<sweep name>/)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help=f"parallel runs on this machine (default: {os.cpu_count()}, the CPU count); "
                             "with --ray local: the CPUs Ray may use")
    parser.add_argument("--ray", metavar="ADDRESS",
                        help="run on Ray: 'local' (start Ray here), 'auto' (the cluster this machine is in) "
                             "or a cluster address such as ray://head:10001 (needs slamfront[ray])")
    parser.add_argument("--cpus-per-run", type=float, default=1.0, metavar="C",
                        help="Ray: CPUs reserved for each run (default 1)")
    parser.add_argument("--shared-dir", action="store_true",
                        help="Ray cluster: DIR is on a filesystem every node sees at the same path, so runs "
                             "write there directly (default: runs send their files back to this machine)")
    parser.add_argument("--worker-data", type=Path, metavar="DIR",
                        help="the data root on the workers (default: each worker's $SLAMFRONT_DATA)")
    parser.add_argument("--max-frames", type=frame_count, metavar="N", help="stop every run after N frames (a smoke campaign)")
    parser.add_argument("--force", action="store_true", help="run again even the runs already finished in DIR")
    parser.add_argument("--dry-run", action="store_true", help="validate the sweep and list its runs; run nothing")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def _backend(args: argparse.Namespace) -> Backend:
    from slamfront.campaign import LocalBackend, RayBackend

    if args.ray:
        return RayBackend(args.ray, args.workers, args.cpus_per_run, shared_dir=True if args.shared_dir else None)
    return LocalBackend(args.workers)


def run(args: argparse.Namespace) -> int:
    from slamfront.campaign import find_sweep, run_campaign

    path = find_sweep(args.sweep)
    if args.dry_run:
        return _dry_run(path, args)
    result = run_campaign(
        path, args.out, _backend(args), force=args.force, progress=False if args.quiet else None,
        max_frames=args.max_frames, data_root=args.worker_data,
    )
    ran = len(result.table.rows) - result.n_skipped - result.count("pending")
    print(f"results: {result.results_csv}")
    print(f"report:  {result.report_path.with_suffix('.html')}")
    print(f"runs:    {len(result.table.rows)} ({ran} ran now, {result.n_skipped} already finished): "
          f"{result.count('ok')} ok, {result.count('failed')} failed, {result.count('pending')} pending")
    for metric in result.table.missing_metrics():
        print(f"warning: no finished run reported {metric!r}; see a run's metrics.json for the names")
    if result.interrupted:
        print("interrupted: run the same command again to resume")
        return 130
    return 1 if result.count("failed") else 0


def _dry_run(path: Path, args: argparse.Namespace) -> int:
    from slamfront.campaign import plan_campaign
    from slamfront.campaign.campaign import default_out_dir
    from slamfront.campaign.store import CampaignStore

    sweep, runs = plan_campaign(path, args.max_frames)
    out_dir = args.out or default_out_dir(sweep)
    finished = CampaignStore(out_dir.resolve()).finished() if not args.force else {}
    for run in runs:
        state = "finished" if run.key in finished else "to run"
        print(f"{run.index:4d}  {state:<8}  {run.name}  {run.describe()}")
    n_done = sum(run.key in finished for run in runs)
    print(f"{sweep.name}: {len(runs)} runs, {n_done} already finished in {out_dir}")
    return 0
