"""Campaign throughput: a 16-run synthetic sweep run serially in-process (the baseline: the
same run function, no campaign machinery), then with ``slamfront sweep`` on the local pool
with 1 and 2 workers and on Ray started locally with 2 CPUs, all in this one run.

Overhead per run, two ways: from wall time, (wall x workers - baseline wall) / runs, which
counts waiting as cost and so needs an idle machine; and from CPU time (this process and its
children, user + system), (CPU - baseline CPU) / runs, which holds on a busy machine too.
Ray's workers are children of its raylet, not of this process, so their CPU time is not seen.

Run: .venv/bin/python benchmarks/bench_sweep.py
"""

from __future__ import annotations

import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.campaign import LocalBackend, RayBackend, plan_campaign, run_campaign, run_one  # noqa: E402
from slamfront.campaign.task import RunTask  # noqa: E402

RUNS = 16
SWEEP = {
    "name": "bench16",
    "recipe": "paired_demo",
    "set": {"source.params.frames_per_traversal": 100, "source.params.route_length_m": 200, "log.images": False},
    "grid": {"loop_detector.params.uniqueness_window": [2, 5, 10, 30], "loop_detector.params.threshold": [0.1, 0.3]},
    "repetitions": 2,
    "repetition_seed": "source.params.seed",
    "metrics": ["recall_at_100p", "auc_pr"],
}


def cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def serial_baseline(sweep_path: Path, scratch: Path) -> tuple[float, float, float]:
    """Wall time and CPU time of the 16 runs one after another in this process, and their summed run time."""
    _, runs = plan_campaign(sweep_path)
    assert len(runs) == RUNS
    cpu = cpu_seconds()
    start = time.perf_counter()
    inside = 0.0
    for run in runs:
        outcome = run_one(RunTask(run.key, run.name, run.recipe, run.origin, str(scratch / run.name),
                                  threads=os.cpu_count() or 1))
        assert outcome.status == "ok", outcome.error
        inside += outcome.metrics["seconds"]
    return time.perf_counter() - start, cpu_seconds() - cpu, inside


def campaign(sweep_path: Path, out: Path, backend: object) -> tuple[float, float]:
    """Wall time and CPU time (this process and its children) of one campaign."""
    cpu = cpu_seconds()
    start = time.perf_counter()
    result = run_campaign(sweep_path, out, backend, progress=False)  # type: ignore[arg-type]
    wall = time.perf_counter() - start
    assert result.count("ok") == RUNS, result.table.rows
    return wall, cpu_seconds() - cpu


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        sweep_path = folder / "bench16.yaml"
        sweep_path.write_text(yaml.safe_dump(SWEEP, sort_keys=False))
        load_before = os.getloadavg()[0]
        base_wall, base_cpu, base_inside = serial_baseline(sweep_path, folder / "serial")
        rows: list[list[object]] = [["serial in-process (baseline)", 1, base_wall, 1.0, 0.0, base_cpu, 0.0]]
        for label, workers, backend, sees_cpu in (
            ("local pool, --workers 1", 1, LocalBackend(1), True),
            ("local pool, --workers 2", 2, LocalBackend(2), True),
            ("Ray local (2 CPUs), incl. Ray start", 2, RayBackend("local", workers=2), False),
        ):
            wall, cpu = campaign(sweep_path, folder / label.split(",")[0].replace(" ", "_") / str(workers), backend)
            rows.append([label, workers, wall, base_wall / wall, (wall * workers - base_wall) / RUNS,
                         cpu if sees_cpu else "n/a", (cpu - base_cpu) / RUNS if sees_cpu else "n/a"])
        load_after = os.getloadavg()[0]
    body = "\n\n".join([
        f"Load average (1 min) {load_before:.1f} before and {load_after:.1f} after: with other jobs on the "
        f"machine, wall times and parallel speed-ups understate what {os.cpu_count()} free cores give.",
        f"Sweep: {RUNS} runs of the paired_demo recipe at 100 + 100 frames (160x120, images not logged): "
        f"uniqueness_window x threshold x 2 seeded repetitions. The runs' own pipeline time summed "
        f"to {base_inside:.1f} s of the baseline's {base_wall:.1f} s (the rest: building worlds, evaluation, reports).",
        table(["mode", "workers", "wall s", "speed-up vs baseline", "overhead/run from wall (s)",
               "CPU s", "overhead/run from CPU (s)"], rows),
    ])
    publish("sweep", "Campaign benchmark (16-run sweep)", body)


if __name__ == "__main__":
    main()
