"""Running a campaign: plan the runs, skip the finished ones, execute the rest on a backend,
record each as it ends, then write the results table, the plots and the report.

Interrupting (Ctrl-C, SIGTERM) stops the workers (a running run finalises its log), keeps
every finished run and still writes the table; running the same command again resumes.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from slamfront.campaign import plots
from slamfront.campaign.backends import Backend
from slamfront.campaign.plan import PlannedRun, plan_runs
from slamfront.campaign.report import write_campaign_report
from slamfront.campaign.results import ResultsTable, build_table, write_csv, write_json
from slamfront.campaign.store import CampaignStore
from slamfront.campaign.sweepfile import Sweep, read_sweep
from slamfront.campaign.task import RunTask, code_fingerprint
from slamfront.evaluation.loops import PR_CURVE_FILE, read_pr_curve
from slamfront.interrupts import Interrupts
from slamfront.outputs import safe_name, same_file


@dataclass
class CampaignResult:
    """What a campaign wrote and how its runs ended."""

    out_dir: Path
    results_csv: Path
    results_json: Path
    report_path: Path
    table: ResultsTable
    n_skipped: int
    """Runs already finished before this invocation (not run again)."""
    interrupted: bool

    def count(self, status: str) -> int:
        return sum(1 for row in self.table.rows if row["status"] == status)


def plan_campaign(sweep_path: Path, max_frames: int | None = None) -> tuple[Sweep, list[PlannedRun]]:
    """Read a sweep file and expand and validate all of its runs."""
    sweep = read_sweep(sweep_path)
    return sweep, plan_runs(sweep, sweep_path, max_frames=max_frames)


def default_out_dir(sweep: Sweep) -> Path:
    return Path("logs") / "sweeps" / safe_name(sweep.name)


def run_campaign(
    sweep_path: Path,
    out_dir: Path | None,
    backend: Backend,
    *,
    force: bool = False,
    progress: bool | None = None,
    max_frames: int | None = None,
    data_root: Path | None = None,
    held: CampaignStore | None = None,
) -> CampaignResult:
    """Run every unfinished run of the sweep and write ``results.csv``, ``results.json``,
    ``report.md`` and the plots into ``out_dir`` (default: ``logs/sweeps/<sweep name>``).

    :param force: run again even the runs already finished in ``out_dir``.
    :param progress: show a progress bar (None: only on a terminal).
    :param data_root: the data root on the workers (default: theirs).
    :param held: ``out_dir``'s store, whose lock the caller already holds (``compare``, which
        writes into the folder before and after the campaign; a second lock would refuse it).
    :raises RecipeError: the sweep or one of its runs is invalid (nothing has run then).
    """
    sweep, runs = plan_campaign(sweep_path, max_frames)
    if held is not None:
        return _run_locked(sweep_path, sweep, runs, held, backend, force, progress, data_root)
    store = CampaignStore((out_dir or default_out_dir(sweep)).resolve())
    with store.locked():  # one campaign per folder at a time
        return _run_locked(sweep_path, sweep, runs, store, backend, force, progress, data_root)


def _run_locked(
    sweep_path: Path, sweep: Sweep, runs: list[PlannedRun], store: CampaignStore, backend: Backend,
    force: bool, progress: bool | None, data_root: Path | None,
) -> CampaignResult:
    out_dir = store.root
    if not same_file(sweep_path, out_dir / "sweep.yaml"):  # resuming from the copy is fine
        shutil.copyfile(sweep_path, out_dir / "sweep.yaml")
    finished = {} if force else store.finished(code_fingerprint())
    planned = {run.key for run in runs}
    if not force and (stale := len(set(store.finished()) & planned) - len(set(finished) & planned)):
        many = stale > 1
        print(f"{out_dir}: {stale} finished run{'s were' if many else ' was'} made by other code (slamfront or its "
              f"plugins changed since): running {'them' if many else 'it'} again", file=sys.stderr)
    folders = {run.key: finished[run.key] for run in runs if run.key in finished}
    records = {key: store.read_record(folder) or {} for key, folder in folders.items()}
    todo = [run for run in runs if run.key not in folders]
    by_key = {run.key: run for run in todo}
    tasks = []
    for run in todo:
        folders[run.key] = store.prepare(run)
        tasks.append(RunTask(
            key=run.key, name=run.name, recipe=run.recipe, origin=run.origin,
            out_dir=str(folders[run.key]) if backend.shared_dir else None, max_frames=run.max_frames,
            threads=backend.threads_per_run, data_root=str(data_root) if data_root else None,
        ))

    bar = tqdm(total=len(runs), initial=len(runs) - len(todo), desc=sweep.name, unit="run",
               disable=None if progress is None else not progress)
    counts = {"ok": 0, "failed": 0}
    interrupted = False
    try:
        if tasks:
            with Interrupts(), backend, contextlib.closing(backend.run(tasks)) as outcomes:
                for outcome in outcomes:
                    run = by_key[outcome.key]
                    if outcome.files is not None:
                        store.save_files(folders[run.key], outcome.files)
                    records[run.key] = store.record(run, folders[run.key], outcome)
                    counts[outcome.status] += 1
                    if outcome.status == "failed":
                        log = folders[run.key] / "run.mcap"
                        where = f" (the log written so far: {log})" if log.is_file() else ""
                        bar.write(f"failed: {run.describe()}: {outcome.error}{where}", file=sys.stderr)
                    bar.set_postfix(counts, refresh=False)
                    bar.update()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()

    metrics = {key: store.read_metrics(folder) for key, folder in folders.items() if key in records}
    table = build_table(sweep, runs, folders, records, metrics, out_dir)
    results_csv = write_csv(table, out_dir / "results.csv")
    results_json = write_json(table, sweep, sweep_path, out_dir / "results.json")
    figures = _plot(table, folders, runs, out_dir)
    report = write_campaign_report(out_dir, sweep, sweep_path, table, figures, len(runs) - len(todo))
    return CampaignResult(out_dir, results_csv, results_json, report, table, len(runs) - len(todo), interrupted)


FIGURE_PATTERNS = ("vs_*.png", "pr.png", "pr_*.png", "methods.png")
"""What :mod:`slamfront.campaign.plots` writes; older ones go before new ones are drawn."""


def _plot(table: ResultsTable, folders: Mapping[str, Path], runs: list[PlannedRun], out_dir: Path) -> list[Path]:
    for pattern in FIGURE_PATTERNS:  # a figure of a parameter the sweep no longer varies would mislead
        for stale in out_dir.glob(pattern):
            stale.unlink()
    curves: dict[int, Any] = {}
    for index, (run, row) in enumerate(zip(runs, table.rows)):
        path = folders[run.key] / PR_CURVE_FILE
        if row["status"] == "ok" and path.is_file():
            _, precision, recall = read_pr_curve(path)
            curves[index] = (recall, precision)
    return [
        *plots.metric_vs_parameter(table, out_dir),
        *plots.methods_side_by_side(table, out_dir),
        *plots.pr_curves(table, curves, out_dir),
    ]
