"""Whole-process profile: where the time of a `slamfront` command goes, and against peers.

Every measurement is a fresh child process, timed from outside (interpreter start
included), one after the other in the same run, so ratios are against peers measured
on the same machine under the same load:

1. each shipped Nordland recipe, as `slamfront run` does it: import, setup (recipe +
   plugins), frame loop (frames, stages, their `finish`, logging), evaluation (metrics
   and their plots), log close, report (metrics.json, report.md), and the rest
   (interpreter start and exit); evaluation as a share of the frame loop;
2. `slamfront optimize` (default options, which write before_after.svg, and
   `--no-plots`) against a plain GTSAM script that does the same read +
   Levenberg-Marquardt + writing of the optimised graph and a TUM trajectory, on M3500
   and sphere2500, with the relative difference of their final costs;
3. `slamfront eval traj` against `evo_ape` (evo, same SE(3) alignment, same answer) on
   the TUM fr1 pair;
4. `slamfront --help` against a bare interpreter start;
5. recipe pairs (``--pairs nordland_hsl:nordland_seqslam``): the two whole processes
   interleaved A B A B, the wall and CPU ratios round by round, each one's evaluation as a
   share of its wall time, and both recalls (the answers must not change with the speed).

Commands are repeated (``--repeats`` rounds after an untimed warm-up, interleaved with
their peer); ratios are the medians of the round-by-round ratios.

Run: .venv/bin/python benchmarks/bench_process.py [--recipes nordland_seqslam ...] [--repeats 5]
     [--peers optimize other] [--pairs nordland_hsl:nordland_seqslam]
     (``--recipes`` / ``--peers`` / ``--pairs`` with no names skip that part; the sections of
     results/process.md a run does not measure are kept as they were)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
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
                  "log_write": m.get("log_write_seconds", 0.0), "recall_at_100p": m.get("recall_at_100p"),
                  "timing": {k: v.get("total_s") for k, v in m.get("timing", {}).items()}}))
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
print(repr(graph.error(result)))
"""

GRAPHS = {
    "M3500": ("posegraphs/slambook/M3500.g2o", "2"),
    "sphere2500": ("posegraphs/se-sync/sphere2500.g2o", "3"),
}
TRAJECTORY = ("trajectories/fr1_gt_vs_est/groundtruth.txt", "trajectories/fr1_gt_vs_est/estimated.txt")


CHILD_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
"""Children run as on a user's machine: with Python's bytecode cache (a development shell may
switch it off, and then every slamfront module is compiled again at each start)."""


def timed(command: list[str]) -> tuple[float, float, str]:
    """Wall seconds of a child process from spawn to exit, its CPU seconds (user + system),
    and its stdout."""
    start = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=CHILD_ENV)
    stdout, stderr = child.communicate()
    seconds = time.perf_counter() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # cumulative: the caller takes differences
    if child.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed: {stderr.strip()[-500:]}")
    return seconds, usage.ru_utime + usage.ru_stime, stdout


def wall(command: list[str]) -> tuple[float, str]:
    """Seconds of a child process from spawn to exit, and its stdout."""
    seconds, _, stdout = timed(command)
    return seconds, stdout


def pair_ratios(ours: list[float], theirs: list[float]) -> str:
    """The median of the pair-by-pair ratios, with their range."""
    ratios = [a / b for a, b in zip(ours, theirs)]
    return f"{median(ratios):.3f} [{min(ratios):.2f}-{max(ratios):.2f}]"


def median(values: list[float]) -> float:
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def profile_recipe(name: str) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        seconds, after, stdout = timed([sys.executable, "-c", RUN_CHILD, name, out])
    phases = json.loads(stdout.strip().splitlines()[-1])
    phases["whole"] = seconds
    phases["cpu"] = after - (before.ru_utime + before.ru_stime)
    return phases


def pair_rows(pairs: list[str], repeats: int) -> list[list[object]]:
    """Whole ``slamfront run`` processes of two recipes, interleaved A B A B after one
    untimed warm-up round (which also fills numba's on-disk cache), ratios round by round."""
    rows = []
    for pair in pairs:
        ours, peer = pair.split(":")
        runs: dict[str, list[dict[str, float]]] = {ours: [], peer: []}
        for attempt in range(repeats + 1):
            for name in (ours, peer):
                phases = profile_recipe(name)
                if attempt:
                    runs[name].append(phases)
            print(pair, attempt, {k: round(v[-1]["whole"], 2) for k, v in runs.items() if v}, flush=True)
        a, b = runs[ours], runs[peer]
        share = [r["evaluation"] / r["whole"] for r in a]
        peer_share = [r["evaluation"] / r["whole"] for r in b]
        stages = {k: median([r["timing"].get(k) or 0.0 for r in a]) for k in a[0]["timing"]}
        rows.append([
            f"`run {ours}` vs `run {peer}`", median([r["whole"] for r in a]), median([r["whole"] for r in b]),
            pair_ratios([r["whole"] for r in a], [r["whole"] for r in b]),
            pair_ratios([r["cpu"] for r in a], [r["cpu"] for r in b]),
            f"{100 * median(share):.0f} % [{100 * min(share):.0f}-{100 * max(share):.0f}]",
            f"{100 * median(peer_share):.0f} %", median([r["evaluation"] for r in a]),
            median([r["evaluation"] for r in b]),
            ", ".join(f"{k} {v:.2f}" for k, v in stages.items()),
            f"{a[0]['recall_at_100p']:.4f} / {b[0]['recall_at_100p']:.4f}", 0.8,
        ])
    return rows


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


def optimize_rows(repeats: int) -> list[list[object]]:
    """``slamfront optimize`` (default options, and ``--no-plots``) against the plain GTSAM
    script, interleaved A B C A B C ..., ratios pair by pair (wall and CPU)."""
    rows = []
    for name, (relative, dim) in GRAPHS.items():
        graph = str(DATA / relative)
        commands = {  # OUT: the output folder
            "default": [str(BIN / "slamfront"), "optimize", graph, "-o", "OUT"],
            "no plots": [str(BIN / "slamfront"), "optimize", graph, "-o", "OUT", "--no-plots"],
            "gtsam": [sys.executable, "-c", GTSAM_SCRIPT, graph, "OUT", dim],
        }
        walls: dict[str, list[float]] = {k: [] for k in commands}
        cpus: dict[str, list[float]] = {k: [] for k in commands}
        costs: dict[str, float] = {}
        for attempt in range(repeats + 1):  # the first round warms the caches and is not counted
            for label, command in commands.items():
                with tempfile.TemporaryDirectory() as out:
                    before = resource.getrusage(resource.RUSAGE_CHILDREN)
                    seconds, after, stdout = timed([out if part == "OUT" else part for part in command])
                    cpu = after - (before.ru_utime + before.ru_stime)
                    if label == "gtsam":
                        costs[label] = float(stdout.strip().splitlines()[-1])
                    else:
                        costs[label] = json.loads((Path(out) / "metrics.json").read_text())["cost_after"]
                if attempt:
                    walls[label].append(seconds)
                    cpus[label].append(cpu)
            print(name, attempt, {k: round(v[-1], 3) for k, v in walls.items() if v}, flush=True)
        difference = abs(costs["default"] - costs["gtsam"]) / costs["gtsam"]
        for label, target in (("default", 1.3), ("no plots", "-")):
            shown = f"`slamfront optimize {name}.g2o`" + (" --no-plots" if label == "no plots" else " (default options)")
            rows.append([shown, median(walls[label]), median(walls["gtsam"]),
                         pair_ratios(walls[label], walls["gtsam"]), pair_ratios(cpus[label], cpus["gtsam"]),
                         f"{difference:.1e}", target])
    return rows


def peer_rows(repeats: int) -> list[list[object]]:
    rows = []
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
                 median(ours), median(theirs), pair_ratios(ours, theirs), "-", "-", 1.1])
    helps, bare = [], []
    for _ in range(repeats):
        helps.append(wall([str(BIN / "slamfront"), "--help"])[0])
        bare.append(wall([sys.executable, "-c", "pass"])[0])
    rows.append(["slamfront --help (peer: python -c pass)", median(helps), median(bare), pair_ratios(helps, bare),
                 "-", "-", "-"])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recipes", nargs="*", default=sorted(p.stem for p in (ROOT / "recipes").glob("nordland_*.yaml")))
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds per command (after one warm-up round)")
    parser.add_argument("--peers", nargs="*", choices=("optimize", "other"), default=["optimize", "other"],
                        help="which peer comparisons to run")
    parser.add_argument("--pairs", nargs="*", default=["nordland_hsl:nordland_seqslam"],
                        help="recipe pairs OURS:PEER whose whole processes are interleaved")
    args = parser.parse_args()
    load_before = os.getloadavg()
    pairs = pair_rows(args.pairs, args.repeats) if args.pairs else []
    optimize = optimize_rows(args.repeats) if "optimize" in args.peers else []
    peers = peer_rows(args.repeats) if "other" in args.peers else []
    recipes = recipes_table(args.recipes) if args.recipes else ""
    load_after = os.getloadavg()
    headers = ["command", "slamfront s", "peer s", "wall ratio [range]", "CPU ratio [range]", "cost difference",
               "target"]
    body = "\n\n".join(part for part in [
        f"Every command a fresh process timed from outside, with Python's bytecode cache, after one untimed "
        f"warm-up round; {args.repeats} rounds, each command interleaved with its peer (A B A B ...); the ratios "
        f"are the medians of the round-by-round ratios, [min-max] beside; seconds are medians. Wall ratios are "
        f"the target; CPU ratios (user + system seconds of the child) move less with the load. Machine load "
        f"(1-min average) {load_before[0]:.1f} before, {load_after[0]:.1f} after, on {os.cpu_count()} cores, "
        f"shared with other jobs: seconds depend on the load, ratios much less.",
        "## Recipe against recipe, whole process" if pairs else "",
        table(["pair (A vs B)", "A whole s", "B whole s", "wall ratio A/B [range]", "CPU ratio A/B [range]",
               "A evaluation / A wall [range]", "B evaluation / B wall", "A evaluation s", "B evaluation s",
               "A stage seconds (median)", "R@100%P A / B", "target wall ratio"], pairs) if pairs else "",
        "Each round runs A then B as fresh `slamfront run` processes (logging, plots and report included, as a "
        "user runs them). *Evaluation* is every evaluation's metrics and plots after the frame loop; the "
        "descriptor retrieval curve in it is exact (every query against every reference), its k nearest found by "
        "a vectorised bound and re-ranked near the cut with the exact distances." if pairs else "",
        "## `slamfront optimize` against a plain GTSAM script" if optimize else "",
        table(headers, optimize) if optimize else "",
        "Peer: `gtsam.readG2o`, a gauge prior, Levenberg-Marquardt (GTSAM's defaults, 100 iterations at most), "
        "`gtsam.writeG2o` and a TUM file. `slamfront optimize` first checks the graph with its own reader "
        "(line-numbered errors, connectivity, positive-definite information), then has `gtsam.readG2o` build the "
        "problem from a plain g2o file (as the script does), and writes initial.tum, metrics.json and report.md, "
        "and by default before_after.svg (SVG text, no imaging library). *Cost difference*: relative difference "
        "of the two final costs." if optimize else "",
        "## Against other peers" if peers else "",
        table(headers, peers) if peers else "",
        "`evo_ape tum GT EST -a --t_max_diff 0.01` for `eval traj --max-difference 0.01` (which also computes "
        "RPE); the same ATE is printed beside." if peers else "",
        "## Nordland recipes: where a `slamfront run` spends its time" if recipes else "",
        recipes,
        "`frame loop` includes the stages' `finish` (SeqSLAM matches all queries there in batch mode) and the "
        "log writing shown in its own column; `evaluation` is every evaluation's metrics and plots after the loop; "
        "`start/exit` is the process's own start and exit (interpreter, atexit) outside the timed phases."
        if recipes else "",
    ] if part)
    publish("process", "Whole-process profile", body, libraries=("numpy", "gtsam", "pillow", "evo", "numba"),
            keep_sections=True)


if __name__ == "__main__":
    main()
