"""Whole-process profile: where the time of a `slamfront` command goes, and against peers.

Every measurement is a fresh child process, timed from outside (interpreter start
included), one after the other in the same run, so ratios are against peers measured
on the same machine under the same load:

1. each shipped Nordland recipe, as `slamfront run` does it: import, setup (recipe +
   plugins), frame loop (frames, stages, their `finish`, logging), evaluation (metrics
   and their plots), log close, report (metrics.json, report.md), and the rest
   (interpreter start and exit); evaluation as a share of the frame loop;
2. `slamfront optimize` (with and without its plot) against a plain GTSAM script that
   does the same read + Levenberg-Marquardt + writing of the optimised graph and a TUM
   trajectory, on M3500 and sphere2500;
3. `slamfront eval traj` against `evo_ape` (evo, same SE(3) alignment, same answer) on
   the TUM fr1 pair;
4. `slamfront --help` against a bare interpreter start.

Commands are repeated (``--repeats``, interleaved with their peer) and the median kept.

Run: .venv/bin/python benchmarks/bench_process.py [--recipes nordland_seqslam ...] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("SLAMFRONT_DATA", ROOT.parent / "shared" / "data"))

RUN_CHILD = """
import json, sys, time
start = time.perf_counter()
from pathlib import Path
from slamfront.recipe import build_pipeline, load_recipe
from slamfront.runtime import run_pipeline
imported = time.perf_counter()
recipe, path = load_recipe(sys.argv[1], [])
pipeline = build_pipeline(recipe, str(path))
built = time.perf_counter()
result = run_pipeline(pipeline, str(path), Path(sys.argv[2]), progress=False)
m = result.metrics
print(json.dumps({"import": imported - start, "setup": built - imported, **result.phase_seconds,
                  "log_write": m.get("log_write_seconds", 0.0), "recall_at_100p": m.get("recall_at_100p")}))
"""

GTSAM_SCRIPT = """
import sys
import gtsam
import numpy as np
path, out, is3d = sys.argv[1], sys.argv[2], sys.argv[3] == "3"
graph, initial = gtsam.readG2o(path, is3d)
first = min(initial.keys())
if is3d:
    graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
else:
    graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)))
params = gtsam.LevenbergMarquardtParams()
params.setMaxIterations(100)
result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
gtsam.writeG2o(graph, result, out + "/optimized.g2o")
keys = sorted(result.keys())
if is3d:
    poses = [result.atPose3(k) for k in keys]
    xyz = np.array([p.translation() for p in poses])
    quat = np.array([[q.x(), q.y(), q.z(), q.w()] for q in (p.rotation().toQuaternion() for p in poses)])
else:
    poses = [result.atPose2(k) for k in keys]
    xyz = np.array([[p.x(), p.y(), 0.0] for p in poses])
    half = np.array([p.theta() for p in poses]) / 2
    quat = np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])
table = np.column_stack([np.array(keys, dtype=float), xyz, quat])
np.savetxt(out + "/trajectory.tum", table, fmt="%.17g")
"""

GRAPHS = {
    "M3500": ("posegraphs/slambook/M3500.g2o", "2"),
    "sphere2500": ("posegraphs/se-sync/sphere2500.g2o", "3"),
}
TRAJECTORY = ("trajectories/fr1_gt_vs_est/groundtruth.txt", "trajectories/fr1_gt_vs_est/estimated.txt")


def wall(command: list[str]) -> tuple[float, str]:
    """Seconds of a child process from spawn to exit, and its stdout."""
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed: {done.stderr.strip()[-500:]}")
    return seconds, done.stdout


def median(values: list[float]) -> float:
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def profile_recipe(name: str) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as out:
        seconds, stdout = wall([sys.executable, "-c", RUN_CHILD, name, out])
    phases = json.loads(stdout.strip().splitlines()[-1])
    phases["whole"] = seconds
    return phases


def recipes_table(names: list[str]) -> str:
    rows = []
    for name in names:
        p = profile_recipe(name)
        print(name, round(p["whole"], 2), flush=True)
        named = ("import", "setup", "frame_loop", "evaluation", "log_close", "report")
        rest = p["whole"] - sum(p[k] for k in named)
        rows.append([name, *(p[k] for k in named), rest, p["whole"], p["log_write"],
                     f"{100 * p['evaluation'] / p['frame_loop']:.0f} %", p["whole"] / p["frame_loop"]])
    return table(
        ["recipe", "import s", "setup s", "frame loop s", "evaluation s", "log close s", "report s",
         "start/exit s", "whole s", "log writing s (in the loop)", "evaluation / loop", "whole / loop"],
        rows,
    )


def peer_rows(repeats: int, plots: bool) -> list[list[object]]:
    rows = []
    for name, (relative, dim) in GRAPHS.items():
        graph = DATA / relative
        ours, theirs, ours_plot = [], [], []
        for _ in range(repeats):  # interleaved: both see the same load
            with tempfile.TemporaryDirectory() as out:
                ours.append(wall([str(BIN / "slamfront"), "optimize", str(graph), "-o", out, "--no-plots"])[0])
            with tempfile.TemporaryDirectory() as out:
                theirs.append(wall([sys.executable, "-c", GTSAM_SCRIPT, str(graph), out, dim])[0])
            if plots:
                with tempfile.TemporaryDirectory() as out:
                    ours_plot.append(wall([str(BIN / "slamfront"), "optimize", str(graph), "-o", out])[0])
        row: list[object] = [f"optimize {name}", median(ours), median(theirs), median(ours) / median(theirs), 1.3]
        rows.append(row)
        if plots:
            rows.append([f"optimize {name} (with before_after.png)", median(ours_plot), median(theirs),
                         median(ours_plot) / median(theirs), "-"])
    gt, est = (str(DATA / p) for p in TRAJECTORY)
    ours, theirs = [], []
    answers = {}
    for _ in range(repeats):
        seconds, stdout = wall([str(BIN / "slamfront"), "eval", "traj", gt, est, "--max-difference", "0.01", "--json"])
        ours.append(seconds)
        answers["slamfront"] = json.loads(stdout)["ate_rmse_m"]
        seconds, stdout = wall([str(BIN / "evo_ape"), "tum", gt, est, "-a", "--t_max_diff", "0.01"])
        theirs.append(seconds)
        answers["evo"] = next(float(line.split()[-1]) for line in stdout.splitlines() if line.strip().startswith("rmse"))
    rows.append([f"eval traj fr1 (ATE {answers['slamfront']:.6f} m; evo_ape {answers['evo']:.6f} m)",
                 median(ours), median(theirs), median(ours) / median(theirs), 1.1])
    helps, bare = [], []
    for _ in range(repeats):
        helps.append(wall([str(BIN / "slamfront"), "--help"])[0])
        bare.append(wall([sys.executable, "-c", "pass"])[0])
    rows.append(["slamfront --help (peer: python -c pass)", median(helps), median(bare), median(helps) / median(bare), "-"])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recipes", nargs="*", default=sorted(p.stem for p in (ROOT / "recipes").glob("nordland_*.yaml")))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-plots", action="store_true", help="skip the optimize runs with their plot")
    args = parser.parse_args()
    load_before = os.getloadavg()
    peers = peer_rows(args.repeats, not args.no_plots)
    recipes = recipes_table(args.recipes) if args.recipes else ""
    load_after = os.getloadavg()
    body = "\n\n".join([
        f"One run, every command a fresh process timed from outside (median of {args.repeats}, interleaved with "
        f"its peer); machine load (1-min average) {load_before[0]:.1f} before, {load_after[0]:.1f} after, on "
        f"{os.cpu_count()} cores. Ratios are the numbers to compare; seconds depend on the load.",
        "## Against peers",
        table(["command", "slamfront s", "peer s", "ratio", "target"], peers),
        "Peers: a plain GTSAM script (`gtsam.readG2o`, gauge prior, Levenberg-Marquardt with 100 iterations, "
        "`gtsam.writeG2o` and a TUM file) for `optimize` (which also writes initial.tum, metrics.json and "
        "report.md, and checks the graph); `evo_ape tum GT EST -a --t_max_diff 0.01` for `eval traj "
        "--max-difference 0.01` (which also computes RPE); the same ATE is printed beside.",
        "## Nordland recipes: where a `slamfront run` spends its time",
        recipes,
        "`frame loop` includes the stages' `finish` (SeqSLAM matches all queries there in batch mode) and the "
        "log writing shown in its own column; `evaluation` is every evaluation's metrics and plots after the loop; "
        "`start/exit` is the process's own start and exit (interpreter, atexit) outside the timed phases.",
    ])
    publish("process", "Whole-process profile", body)


if __name__ == "__main__":
    main()
