"""Generated stress benchmark: every loop detector's operating point on cases drawn at random.

The cases (``stress_seeds.json``, drawn once by ``--draw`` from the master seed written in
it; :mod:`stress_cases`) are sub-windows of 30-300 frames of the Nordland route (summer /
winter) and of four synthetic street worlds (day / dusk or night), with the roles of
reference and query swapped, the query reversed, re-paced (0.5x-2x, constant or smoothly
varying), with stops or with a jump, or unchanged. Every detector of the generalisation
sweep (``sweeps/generalisation.yaml``) plus OpenSeqSLAM runs with its shipped recipe,
only the source swapped for the case's frames. Per detector: precision at the operating
point (minimum, 5th percentile, mean over the cases that accept something), recall there,
R@100%P, AUC-PR, how often it accepts nothing and why, and the recall rule
(recall at the operating point >= 0.5 x R@100%P - 0.02) on the unchanged cases; per
family too; cases listed as ``shaped`` in the seeds file are reported apart.

Run: nice -n 10 .venv/bin/python benchmarks/bench_stress.py [--detectors ...] [--limit N] [--workers 2]
     --from-csv re-renders the page from benchmarks/results/stress.csv; --draw writes a new case list
     (only when the benchmark's case families change: never to pick cases by their results).
Finished cases are kept in stress.csv (by detector, case and the code's commit), so the same command resumes.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

import stress_cases  # noqa: E402
from common import publish, table  # noqa: E402

from slamfront.campaign.sweepfile import sweeps_dir  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402

HERE = Path(__file__).resolve().parent
SEEDS = HERE / "stress_seeds.json"
CSV = HERE / "results" / "stress.csv"
IMAGE = HERE / "results" / "stress.png"
CACHE = HERE.parent / "logs" / "stress"
"""Rendered synthetic worlds and the cases' link folders (not committed)."""
MASTER_SEED = 20261202
N_CASES = 300
QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
MIN_PRECISION = 0.95
FIELDS = ["recall_at_100p", "auc_pr", "precision_at_operating_point", "recall_at_operating_point", "n_accepted",
          "accept_threshold", "n_queries_with_true_match", "seconds"]
COLUMNS = ["detector", "case", "commit", *FIELDS, "declined", "error"]


def detectors() -> dict[str, tuple[str, list[str]]]:
    """Detector name -> (recipe, overrides): the generalisation sweep's recipes, and OpenSeqSLAM's."""
    sweep = yaml.safe_load((sweeps_dir() / "generalisation.yaml").read_text())
    out: dict[str, tuple[str, list[str]]] = {}
    for name, spec in sweep["recipes"].items():
        sets = [f"{k}={yaml.safe_dump(v, default_flow_style=True).strip()}"
                for k, v in (spec.get("set") or {}).items() if not k.startswith("source")]
        out[name] = (spec["recipe"], sets)
    out["openseqslam"] = ("nordland_openseqslam", [])
    return out


def nordland_root() -> Path:
    from slamfront_plugins.sources.paired_datasets import dataset_folder  # where the nordland source reads

    return dataset_folder(None, "nordland")


def render_world(world: int) -> dict[str, Path]:
    """Folders of a synthetic world's day, dusk and night traversals (rendered once into the cache)."""
    import cv2

    folder = CACHE / f"synthetic_{world}"
    lights = {"day": folder / "day", **{light: folder / light for light in stress_cases.LIGHTS}}
    if all(p.is_dir() and len(list(p.iterdir())) == stress_cases.SYNTHETIC_FRAMES for p in lights.values()):
        return lights
    for n, light in enumerate(stress_cases.LIGHTS):
        recipe, _ = load_recipe("synthetic_hsl", [
            f"source.params.seed={world}", f"source.params.query_illumination={light}",
            f"source.params.frames_per_traversal={stress_cases.SYNTHETIC_FRAMES}",
            f"source.params.route_length_m={stress_cases.SYNTHETIC_FRAMES}"])
        source = build_pipeline(recipe, "synthetic_hsl").source
        for frame in source.frames():
            side = "day" if frame.traversal == "reference" else light
            if side == "day" and n > 0:
                continue
            lights[side].mkdir(parents=True, exist_ok=True)
            image = frame.image if frame.image.ndim == 2 else cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)
            cv2.imwrite(str(lights[side] / f"{frame.sequence_index:05d}.png"), image)
    return lights


def folders_of(case: dict[str, Any]) -> dict[str, Path]:
    if case["pair"] == "nordland":
        root = nordland_root()
        return {"summer": root / "summer", "winter": root / "winter"}
    return render_world(case["world"])


def declined_reason(metrics: dict[str, Any]) -> str:
    """Why a run accepted nothing, from what its metrics say (empty when it accepted something)."""
    if float(metrics.get("n_accepted") or 0) > 0:
        return ""
    for key in ("accept_declined", "accept_reason", "declined_reason", "no_accept_reason"):
        if metrics.get(key):
            return str(metrics[key])
    if float(metrics.get("recall_at_100p") or 0) == 0 and float(metrics.get("auc_pr") or 0) == 0:
        return "no answers ranked (e.g. a reference too short for the sequence)"
    threshold = metrics.get("accept_threshold")
    return f"nothing above its threshold ({float(threshold):.3g})" if threshold not in (None, "") else "not said"


def run_case(detector: str, case: dict[str, Any], scratch: str) -> dict[str, Any]:
    recipe, sets = detectors()[detector]
    folder = Path(scratch) / f"{detector}_{case['case']}"
    params = stress_cases.lay_out(case, folders_of(case), CACHE / "cases" / f"{detector}_{case['case']}")
    overrides = [*sets, *QUICK, "source.plugin=paired_folders",
                 f"source.params={yaml.safe_dump(params, default_flow_style=True).strip()}"]
    loaded, path = load_recipe(recipe, overrides)
    began = time.perf_counter()
    metrics = dict(run_pipeline(build_pipeline(loaded, str(path)), str(path), folder, progress=False).metrics)
    metrics["seconds"] = time.perf_counter() - began
    row = {k: metrics.get(k, "") for k in FIELDS}
    row["declined"] = declined_reason(metrics)
    return row


def commit() -> str:
    """The last commit that changed the code the runs depend on (not the benchmark's own commits)."""
    try:
        return subprocess.run(["git", "log", "-1", "--format=%h", "--", "framework", "plugins", "recipes", "sweeps"],
                              capture_output=True, text=True,
                              cwd=HERE.parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open() as f:
        return list(csv.DictReader(f))


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = sorted(rows, key=lambda r: (r["detector"], r["case"]))
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})


def number(row: dict[str, Any], key: str) -> float:
    value = row.get(key)
    return float(value) if value not in (None, "") else float("nan")


def accepted(row: dict[str, Any]) -> bool:
    return number(row, "n_accepted") > 0


def rule_met(row: dict[str, Any]) -> bool:
    """Recall at the operating point >= 0.5 x R@100%P - 0.02."""
    return number(row, "recall_at_operating_point") >= 0.5 * number(row, "recall_at_100p") - 0.02


def summary_line(name: str, rows: list[dict[str, Any]], unchanged: list[dict[str, Any]]) -> list[object]:
    """min / 5th percentile / mean precision at the operating point (cases that accept), and the rest."""
    precisions = np.array([number(r, "precision_at_operating_point") for r in rows if accepted(r)])

    def mean(key: str) -> str:
        values = [number(r, key) for r in rows]
        values = [v for v in values if np.isfinite(v)]
        return f"{np.mean(values):.3f} ± {np.std(values):.3f}" if values else "-"

    declined = sum(not accepted(r) for r in rows)
    below = int(np.sum(precisions < MIN_PRECISION))
    met = sum(rule_met(r) for r in unchanged)
    return [name, len(rows),
            f"{precisions.min():.3f}" if len(precisions) else "-",
            f"{np.percentile(precisions, 5):.3f}" if len(precisions) else "-",
            f"{precisions.mean():.3f}" if len(precisions) else "-",
            f"{below} ({below / len(precisions):.0%})" if len(precisions) else "-",
            mean("recall_at_operating_point"), mean("recall_at_100p"), mean("auc_pr"),
            f"{declined} ({declined / len(rows):.0%})",
            f"{met} of {len(unchanged)}" if unchanged else "-"]


HEADERS = ["detector", "cases", "precision at op. point: min", "5th pct", "mean", "cases < 95 % right",
           "recall at op. point mean ± sd", "R@100%P mean ± sd", "AUC-PR mean ± sd", "accepts nothing",
           "recall rule met (unchanged cases)"]


def declined_table(rows: list[dict[str, Any]]) -> list[list[object]]:
    out: list[list[object]] = []
    for name in sorted({r["detector"] for r in rows}):
        reasons = Counter(str(r["declined"]).split(" (")[0] for r in rows if r["detector"] == name and not accepted(r))
        out.append([name, "; ".join(f"{reason}: {count}" for reason, count in reasons.most_common()) or "-"])
    return out


def plot(rows: list[dict[str, Any]], names: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.4 * len(names) + 2, 3.6), dpi=110)
    data = [[number(r, "precision_at_operating_point") for r in rows if r["detector"] == n and accepted(r)] or [np.nan]
            for n in names]
    ax.boxplot(data, whis=(5, 95), showmeans=True)
    for k, values in enumerate(data, 1):
        ax.plot(np.full(len(values), k) + np.random.default_rng(k).uniform(-0.15, 0.15, len(values)), values, ".",
                ms=2, alpha=0.4, color="tab:blue")
    ax.axhline(MIN_PRECISION, color="tab:red", lw=1, ls="--")
    ax.axhline(0.85, color="0.5", lw=1, ls=":")
    ax.set_xticks(range(1, len(names) + 1), names, fontsize=8, rotation=15)
    ax.set_ylabel("precision at the operating point")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("Generated stress cases (whiskers 5th-95th percentile; red: 95 %, grey: 85 %)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def render(rows: list[dict[str, Any]], seeds: dict[str, Any], command: str, note: str) -> None:
    cases = {c["case"]: c for c in seeds["cases"]}
    shaped = set(seeds.get("shaped", []))
    rows = [r for r in rows if r["case"] in cases and not r.get("error")]
    names = [n for n in detectors() if any(r["detector"] == n for r in rows)]
    lines, untouched, families = [], [], []
    for name in names:
        mine = [r for r in rows if r["detector"] == name]
        unchanged = [r for r in mine if stress_cases.families(cases[r["case"]]) == ["unchanged"]]
        lines.append(summary_line(name, mine, unchanged))
        clean = [r for r in mine if r["case"] not in shaped]
        untouched.append(summary_line(name, clean, [r for r in unchanged if r["case"] not in shaped]))
        for family in (*stress_cases.FAMILIES, "unchanged"):
            part = [r for r in mine if family in stress_cases.families(cases[r["case"]])]
            if part:
                families.append(summary_line(f"{name} / {family}", part,
                                             part if family == "unchanged" else []))
        for pair in ("nordland", "synthetic"):
            part = [r for r in mine if cases[r["case"]]["pair"] == pair]
            if part:
                families.append(summary_line(f"{name} / {pair} pairs", part, []))
    errors = [r for r in read_csv(CSV) if r.get("error")]
    seconds = [number(r, "seconds") for r in rows]
    cpu = next((line.split(":", 1)[1].strip() for line in subprocess.run(
        ["lscpu"], capture_output=True, text=True).stdout.splitlines() if line.startswith("Model name")),
        platform.processor() or "unknown")
    families_count = Counter(f for c in seeds["cases"] for f in stress_cases.families(c))
    body = "\n\n".join([
        f"Command: `{command}` ({note}). CPU: {cpu}. Code: commit(s) "
        f"{', '.join(sorted({r['commit'] for r in rows}))}. {len(rows)} runs, "
        f"{np.nansum(seconds) / 60:.0f} min of run time ({np.nanmean(seconds):.1f} s a run on average).",
        f"{len(seeds['cases'])} cases drawn once from master seed {seeds['master_seed']} "
        "(`benchmarks/stress_seeds.json`): a sub-window of 30-300 frames of the Nordland route (summer reference, "
        f"winter query) or of a synthetic street world ({', '.join(map(str, stress_cases.SYNTHETIC_WORLDS))}; day "
        "reference, dusk or night query), then, drawn independently, the roles swapped, the query reversed, "
        "re-paced (0.5x-2x, constant or varying smoothly), with 1-3 stops of 5-40 frames, or with a jump (15-40 % "
        f"of the window skipped or driven again); a quarter unchanged. Query passes are cut at "
        f"{stress_cases.MAX_QUERY} frames. Families (a case may be in several): "
        + ", ".join(f"{f} {n}" for f, n in sorted(families_count.items())) + ". Ground truth: the reference frame "
        f"each query frame shows, zeta = {stress_cases.TOLERANCE}. Every detector uses its shipped recipe (those "
        "of the generalisation benchmark, and `nordland_openseqslam`); only the source is swapped.",
        "Precision at the operating point is over the cases where the detector accepts something (min, 5th "
        "percentile, mean); the other columns over every case. The recall rule: recall at the operating point >= "
        "0.5 x R@100%P - 0.02, counted on the unchanged cases.",
        "## Every case\n\n" + table(HEADERS, lines),
        f"## Untouched cases (not in the `shaped` list: {len(shaped)} cases shaped a design decision)\n\n"
        + table(HEADERS, untouched),
        "## Why a detector accepted nothing\n\n" + table(["detector", "reasons (cases)"], declined_table(rows)),
        "## Per family and pair\n\n(the recall rule is counted on the unchanged family only)\n\n"
        + table(HEADERS, families),
        "![precision at the operating point per detector](stress.png)",
        ("Failed runs:\n\n" + "\n".join(f"- {r['detector']} / {r['case']}: {r['error']}" for r in errors))
        if errors else "Every run finished.",
    ])
    plot(rows, names, IMAGE)
    publish("stress", "Generated stress cases: every loop detector's operating point", body)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detectors", nargs="+", help=f"only these (default: all of {list(detectors())})")
    parser.add_argument("--limit", type=int, help="only the first N cases")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--from-csv", action="store_true", help="re-render the page from stress.csv, run nothing")
    parser.add_argument("--draw", action="store_true", help=f"write {SEEDS.name} anew ({N_CASES} cases)")
    parser.add_argument("--master-seed", type=int, default=MASTER_SEED)
    args = parser.parse_args()
    if args.draw:
        import json

        SEEDS.write_text(json.dumps(stress_cases.draw(args.master_seed, N_CASES), indent=1) + "\n")
        print(f"wrote {SEEDS}")
        return
    known = detectors()
    chosen = args.detectors or list(known)
    unknown = sorted(set(chosen) - set(known))
    if unknown:
        raise SystemExit(f"--detectors: unknown {unknown}; known: {list(known)}")
    seeds = stress_cases.read_seeds(SEEDS)
    cases = seeds["cases"][: args.limit] if args.limit else seeds["cases"]
    code = commit()
    rows = read_csv(CSV)
    done = {(r["detector"], r["case"]) for r in rows if r["commit"] == code and not r.get("error")}
    jobs = [] if args.from_csv else [(d, c) for c in cases for d in chosen if (d, c["case"]) not in done]
    load = os.getloadavg()[0]
    for case in {c["case"]: c for _, c in jobs if c["pair"] == "synthetic"}.values():
        render_world(case["world"])  # once, before the workers need it
    with tempfile.TemporaryDirectory() as scratch, ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(run_case, d, c, scratch): (d, c["case"]) for d, c in jobs}
        for n, future in enumerate(as_completed(futures), 1):
            detector, case = futures[future]
            row: dict[str, Any] = {"detector": detector, "case": case, "commit": code}
            try:
                row.update(future.result())
            except Exception as error:  # one failing case is reported, not fatal
                row["error"] = str(error).splitlines()[0][:200]
            rows = [r for r in rows if (r["detector"], r["case"]) != (detector, case)] + [row]
            if n % 10 == 0 or n == len(jobs):
                write_csv(CSV, rows)  # so an interrupted run resumes from here
            print(f"[{n}/{len(jobs)}] {detector} {case} {row.get('seconds', '')!s:.6} "
                  f"P {row.get('precision_at_operating_point', '')!s:.5} {row.get('error', '')}", file=sys.stderr)
    write_csv(CSV, rows)
    command = "nice -n 10 .venv/bin/python benchmarks/bench_stress.py" + (
        f" --detectors {' '.join(args.detectors)}" if args.detectors else "") + (
        f" --limit {args.limit}" if args.limit else "")
    render(rows, seeds, command, "re-rendered from stress.csv" if args.from_csv else
           f"{args.workers} workers, 1-min load {load:.1f} at the start")


if __name__ == "__main__":
    main()
