"""Ablation of the frame-level hierarchical detector (``hierarchical_sequence``): each switch and
tuned constant changed alone, measured on the rows of the generalisation benchmark that did
not shape it.

What shaped what (from the project's history; see docs/results.md):
- every default was chosen on Nordland frames 2900-3575, synthetic world seeds 100-102 and
  (the stream confidence) demo worlds 100-102, none of them a row here; but the whole route
  and experiments 2 and 3 contain frames 2900-3575, and whole-route runs were looked at while
  the frame-level design was worked out: those three rows shaped everything;
- level 3's realignment along Q's own trajectory, with placements that may leave the map
  with half of Q inside, was found on frames 0-2899 (queries 121-178, in the first chunks of
  646 and 200) and experiment 3: those rows shaped ``realign`` and its two constants;
- the line check and the uniqueness operating point were accepted by their scores on the
  whole route, experiments 2 and 3, frames 0-2899 and synthetic world 3 at night: those rows
  shaped them. Their clean test is jumps in the map
  the generalisation rows do not have: seven of the held-out jump variants of
  ``bench_hierarchical_jumps.py`` (run once after that design; the eighth was looked at since)
  are added for them;
- ``confidence: auto``, the distance operating point and ``exclude_recent_places`` concern
  streams, which the generalisation benchmark has none of: they are measured on the demo's
  worlds 0-4 (one stream of two laps each, back end left out), their design being worlds
  100-102;
- the operating point is ``accept: auto`` now (calibrated on the reference or a stream's first
  frames at a false-accept rate of 0.01, the rule designed looking at the first chunk of 646,
  synthetic world 0 at dusk and demo world 0): the former fixed points and another rate are
  measured on the jump rows and the demo worlds;
- the cone of speeds (``speed_search: cone``) was designed on Nordland 2900-3499 re-timed and is
  measured against the fixed-speed lines on the jump rows (none of them changes pace: the cone's
  own test is ``bench_speed_direction.py``); ``cone_near_anchor`` was designed on the four design
  jump variants, the jump variant reordered 300-399 and the rows that shaped the frame-level detector
  (bench_generalisation.py's SHAPED), which include the operating point's design rows and the
  first chunk of 200, measured here on the jump rows too.

The shipped defaults also run on the whole route and experiments 2 and 3 (marked: they
shaped everything), so the table holds the detector's numbers on all 24 generalisation rows.
benchmarks/results/hierarchical_ablation_before.md is this table for the detector before
three things it found not to pay were removed (the cut where the route leaves the line,
the cut at featureless stretches, the screening at speed 1).

Each row's descriptors are computed once (``records/``), then the place map and the detector
run again from the logged descriptors (``slamfront replay --from place_map``) for every
setting. Settings that are not config fields (constants in the code) are changed by
patching the module for that run only. Finished runs are kept, so the command resumes.

Run: nice .venv/bin/python benchmarks/bench_hierarchical_ablation.py [--workers 2] [--out logs/ablation]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import json
import os
import re
import shutil
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, cpu_model, publish, table  # noqa: E402

QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
KEYS = ("recall_at_100p", "auc_pr", "correct_answer_ceiling", "precision_at_operating_point",
        "recall_at_operating_point", "n_distances")

SHAPED_ALL = {"nordland_whole", "nordland_exp2", "nordland_exp3"}
SHAPED_REALIGN = SHAPED_ALL | {"nordland_0_2899", "nordland_646_a", "nordland_200_a"}
SHAPED_JUMPS = SHAPED_ALL | {"nordland_0_2899", "synthetic_3_night"}
JUMPS = [f"jump_{e}_{s}_{n}" for e in ("reordered", "replaced") for s, n in ((100, 100), (300, 100), (450, 150), (250, 200))
         if (e, s) != ("replaced", 100)]
DEMOS = [f"demo_{seed}" for seed in range(5)]


def rows() -> dict[str, list[str]]:
    """Every row: name -> overrides of its recipe (``nordland_hsl``, or ``demo`` for demo_*)."""
    sweep = yaml.safe_load((Path(__file__).resolve().parent.parent / "sweeps" / "generalisation.yaml").read_text())
    out = {name: [f"{k}={yaml.safe_dump(v, default_flow_style=True, width=1000).strip().removesuffix('...').strip()}"
                  for k, v in variant.items()] for name, variant in sweep["variants"].items()}
    for name in JUMPS:
        _, experiment, start, length = name.split("_")
        out[name] = ["source.params.start=2900", f"source.params.experiment={experiment}",
                     f"source.params.block_start={start}", f"source.params.block_length={length}"]
    for name in DEMOS:
        out[name] = [f"source.params.seed={name.split('_')[1]}", "backend=null"]
    return out


@dataclass
class Setting:
    """One ablation: a label, what it changes, and the rows it is measured on."""

    item: str
    label: str
    overrides: list[str] = field(default_factory=list)
    patch: str = ""
    rows: str = "clean"
    """clean: the generalisation rows outside SHAPED_ALL; realign / jumps: outside those sets
    (jumps: plus the jump test variants); demo: the demo worlds."""


SETTINGS = [
    Setting("shipped", "shipped defaults", rows="everything"),
    Setting("track", "track: false", ["loop_detector.params.track=false"]),
    Setting("realign", "realign: false", ["loop_detector.params.realign=false"], rows="realign"),
    Setting("isolate", "isolate: false", ["loop_detector.params.isolate=false"]),
    Setting("line_check", "line_check: false", ["loop_detector.params.line_check=false"], rows="jumps"),
    Setting("refine", "refine: 0 (every level-1 candidate in full)", ["loop_detector.params.refine=0"]),
    Setting("refine", "refine: 1", ["loop_detector.params.refine=1"]),
    Setting("refine", "refine: 6", ["loop_detector.params.refine=6"]),
    Setting("confidence", "confidence: distance (paired rows; auto = uniqueness there)",
            ["loop_detector.params.confidence=distance"]),
    Setting("confidence", "confidence: uniqueness (streams; auto = distance there)",
            ["loop_detector.params.confidence=uniqueness"], rows="demo"),
    Setting("evidence_iterations", "evidence_iterations: 1", ["loop_detector.params.evidence_iterations=1"]),
    Setting("evidence_iterations", "evidence_iterations: 6", ["loop_detector.params.evidence_iterations=6"]),
    Setting("sequence_frames", "sequence_frames: 20", ["loop_detector.params.sequence_frames=20"]),
    Setting("sequence_frames", "sequence_frames: 80", ["loop_detector.params.sequence_frames=80"]),
    Setting("speed_search (cone)", "speed_search: lines (fixed-speed lines vmin..vmax, the default before the cone)",
            ["loop_detector.params.speed_search=lines"], rows="jumps"),
    Setting("cone_near_anchor (on)", "cone_near_anchor: false (the cone's stages on the window's last rows)",
            ["loop_detector.params.cone_near_anchor=false"], rows="jumps"),
    Setting("vmin, vmax", "vmin = vmax = 1", ["loop_detector.params.vmin=1.0", "loop_detector.params.vmax=1.0"]),
    Setting("vmin, vmax", "vmin 0.6, vmax 1.6", ["loop_detector.params.vmin=0.6", "loop_detector.params.vmax=1.6"]),
    Setting("anchor_slack", "anchor_slack: 0", ["loop_detector.params.anchor_slack=0"]),
    Setting("anchor_slack", "anchor_slack: 4", ["loop_detector.params.anchor_slack=4"]),
    Setting("uniqueness_window", "uniqueness_window: 5", ["loop_detector.params.uniqueness_window=5"]),
    Setting("uniqueness_window", "uniqueness_window: 20", ["loop_detector.params.uniqueness_window=20"]),
    Setting("screen_frames", "screen_frames: 3", ["loop_detector.params.screen_frames=3"]),
    Setting("screen_frames", "screen_frames: 12", ["loop_detector.params.screen_frames=12"]),
    Setting("alpha", "alpha: 3 frames", ["loop_detector.params.alpha=3"]),
    Setting("alpha", "alpha: 10 frames", ["loop_detector.params.alpha=10"]),
    Setting("accept: auto (rate 0.01)", "accept: 0.04 (the former fixed uniqueness point)",
            ["loop_detector.params.accept=0.04"], rows="jumps"),
    Setting("accept: auto (rate 0.01)", "false_accept_rate: 0.05", ["loop_detector.params.false_accept_rate=0.05"],
            rows="jumps"),
    Setting("accept: auto (rate 0.01)", "accept: 0.75 (the former fixed distance point)",
            ["loop_detector.params.accept=0.75"], rows="demo"),
    Setting("accept: auto (rate 0.01)", "false_accept_rate: 0.05 (streams)",
            ["loop_detector.params.false_accept_rate=0.05"], rows="demo"),
    Setting("pair cache (4 x sequence_frames)", "pair cache 8 x sequence_frames", patch="keep_x2"),
    Setting("MIN_INSIDE (half of the rows)", "all rows inside the map", patch="inside_all", rows="realign"),
    Setting("MIN_INSIDE (half of the rows)", "a quarter of the rows inside", patch="inside_quarter", rows="realign"),
    Setting("own trajectory (reaches back > slack / (vmax - vmin))", "never realigned along Q's own",
            patch="own_never", rows="realign"),
    Setting("own trajectory (reaches back > slack / (vmax - vmin))", "always realigned along Q's own too",
            patch="own_always", rows="realign"),
    Setting("screening speeds (the detector's, vmin..vmax)", "screening at speed 1 only (as before)",
            patch="screen_speed_1"),
    Setting("exclude_recent_places", "exclude_recent_places: 10", ["loop_detector.params.exclude_recent_places=10"],
            rows="demo"),
    Setting("exclude_recent_places", "exclude_recent_places: 40", ["loop_detector.params.exclude_recent_places=40"],
            rows="demo"),
    Setting("line check shifts (slack+1 .. uniqueness_window)", "line check shifts 3-6", patch="line_3_6",
            rows="jumps"),
    Setting("line check shifts (slack+1 .. uniqueness_window)", "line check shifts 3-15", patch="line_3_15",
            rows="jumps"),
    Setting("speed step (1 / sequence_frames)", "speed step 2 / sequence_frames", patch="step_coarse"),
    Setting("speed step (1 / sequence_frames)", "speed step 1 / (2 sequence_frames)", patch="step_fine"),
]


def rows_of(setting: Setting, names: list[str]) -> list[str]:
    generalisation = [n for n in names if not n.startswith(("jump_", "demo_"))]
    if setting.rows == "everything":
        return list(names)
    if setting.rows == "generalisation":
        return generalisation
    if setting.rows == "shaped":
        return [n for n in generalisation if n in SHAPED_ALL]
    if setting.rows == "demo":
        return list(DEMOS)
    shaped = {"clean": SHAPED_ALL, "realign": SHAPED_REALIGN, "jumps": SHAPED_JUMPS}[setting.rows]
    return [n for n in generalisation if n not in shaped] + (list(JUMPS) if setting.rows == "jumps" else [])


@contextlib.contextmanager
def patched(name: str) -> Iterator[None]:
    """Change one constant in the code for the runs inside (this process only)."""
    import slamfront_plugins.loop_detectors.hierarchical_frames as frames
    import slamfront_plugins.loop_detectors.hierarchical_sequence as sequence

    detector = sequence.HierarchicalSequence

    def wrap(function: Callable, **changes: Callable) -> Callable:
        def call(*args, **kwargs):  # type: ignore[no-untyped-def]
            for key, change in changes.items():
                kwargs[key] = change(args, kwargs)
            return function(*args, **kwargs)
        return call

    def line(window: int) -> Callable:
        return lambda distances, rows, line_, slack, _, *rest: frames.line_uniqueness(distances, rows, line_, slack,
                                                                                     window, *rest)

    changes: dict[str, tuple[object, str, object]] = {
        "keep_x2": (sequence, "PairDistances",
                    lambda compute, keep, **kw: frames.PairDistances(compute, 2 * keep, **kw)),
        "inside_all": (frames, "MIN_INSIDE", 1.0),
        "inside_quarter": (frames, "MIN_INSIDE", 0.25),
        "own_never": (detector, "_reaches_back", lambda self, waiting, record: False),
        "own_always": (detector, "_reaches_back", lambda self, waiting, record: True),
        "screen_speed_1": (sequence, "compare_candidates",
                           wrap(frames.compare_candidates, screen_speeds=lambda a, k: np.clip([1.0], k["velocities"][0],
                                                                                               k["velocities"][-1]))),
        "line_3_6": (sequence, "line_uniqueness", line(6)),
        "line_3_15": (sequence, "line_uniqueness", line(15)),
        "step_coarse": (sequence, "speeds", lambda vmin, vmax, n: frames.speeds(vmin, vmax, n // 2)),
        "step_fine": (sequence, "speeds", lambda vmin, vmax, n: frames.speeds(vmin, vmax, 2 * n)),
    }
    if not name:
        yield
        return
    owner, attribute, value = changes[name]
    old = getattr(owner, attribute)
    setattr(owner, attribute, value)
    try:
        yield
    finally:
        setattr(owner, attribute, old)


def record(name: str, overrides: list[str], out: Path) -> None:
    """Run the row once (descriptors computed and logged) into ``out/records/<name>``."""
    from slamfront.recipe import build_pipeline, load_recipe
    from slamfront.runtime import run_pipeline

    folder = out / "records" / name
    if (folder / "metrics.json").exists():
        return
    loaded, path = load_recipe("demo" if name.startswith("demo_") else "nordland_hsl", [*QUICK, *overrides])
    run_pipeline(build_pipeline(loaded, str(path)), str(path), folder, progress=False)


def code_version() -> str:
    """A digest of the detector's and the place map's source: finished runs are kept per
    version, so a run of other code is never reused."""
    import slamfront_plugins

    root = Path(slamfront_plugins.__file__).parent
    files = sorted((root / "loop_detectors").glob("hierarchical*.py")) + [
        root / "loop_detectors" / "place_sequences.py", root / "place_maps" / "hierarchical.py"]
    return hashlib.sha256(b"".join(f.read_bytes() for f in files)).hexdigest()[:12]


def replay(name: str, setting: Setting, out: Path) -> dict:
    """The row's place map and detector run again with ``setting``; its metrics."""
    from slamfront.recipe import apply_overrides, parse_recipe
    from slamfront.replay import log_recipe_data, replay_log

    label = re.sub(r"[^a-z0-9]+", "_", setting.label.lower()).strip("_")
    folder = out / "runs" / code_version() / label / name
    done = folder / "metrics.json"
    if not done.exists():
        log = out / "records" / name / "run.mcap"
        origin = f"{log}:recipe.yaml"
        recipe = parse_recipe(apply_overrides(log_recipe_data(log), setting.overrides), origin)
        with patched(setting.patch):
            replay_log(log, folder, recipe, origin, "place_map", progress=False)
        for produced in folder.iterdir():  # keep the metrics, not the log (hundreds of runs)
            if produced.name != "metrics.json":
                shutil.rmtree(produced) if produced.is_dir() else produced.unlink()
    metrics = json.loads(done.read_text())
    return {key: float(metrics[key]) for key in KEYS if key in metrics}


def spread(values: list[float]) -> str:
    return f"{np.mean(values):.3f} ± {np.std(values):.3f} ({min(values):.3f})" if values else "-"


def summarise(results: dict[tuple[int, str], dict]) -> tuple[list[list[object]], list[list[object]]]:
    names = list(rows())
    body, csv_rows = [], []
    references = [Setting("shipped", f"shipped defaults, {kind} rows", rows=kind)
                  for kind in ("generalisation", "shaped", "clean", "realign", "jumps", "demo")]
    for index, setting in [(0, r) for r in references] + list(enumerate(SETTINGS))[1:]:
        clean = rows_of(setting, names)
        got = [(n, results[(index, n)], results[(0, n)]) for n in clean if (index, n) in results and (0, n) in results]
        if not got:
            continue
        r100 = [m["recall_at_100p"] for _, m, _ in got]
        delta = [m["recall_at_100p"] - s["recall_at_100p"] for _, m, s in got]
        better, worse = sum(d > 0.0005 for d in delta), sum(d < -0.0005 for d in delta)
        distances = np.mean([m["n_distances"] / s["n_distances"] for _, m, s in got])
        # precision at the operating point over the rows where it accepts something (the
        # evaluation writes 0 when nothing is accepted: recall 0 too)
        accepting = [m for _, m, _ in got if m.get("recall_at_operating_point", 0) > 0]
        precision = [m["precision_at_operating_point"] for m in accepting]
        recall_op = [m.get("recall_at_operating_point", np.nan) for _, m, _ in got]
        silent = f", accepts nothing on {len(got) - len(accepting)}" if len(accepting) < len(got) else ""
        body.append([
            setting.item, setting.label, f"{len(got)} ({setting.rows})", spread(r100),
            f"{np.mean(delta):+.3f} (min {min(delta):+.3f}; {better} up, {worse} down)",
            spread([m["auc_pr"] for _, m, _ in got]), f"{np.mean([m['correct_answer_ceiling'] for _, m, _ in got]):.3f}",
            f"{min(precision) if accepting else float('nan'):.3f} / {np.mean(recall_op):.3f}{silent}", f"{distances:.2f}x",
        ])
        if setting.label.startswith("shipped defaults,"):
            continue
        csv_rows += [[setting.item, setting.label, n, *(m.get(k, "") for k in KEYS)] for n, m, _ in got]
    csv_rows = [["shipped", "shipped defaults", n, *(results[(0, n)].get(k, "") for k in KEYS)]
                for n in names if (0, n) in results] + csv_rows
    return body, csv_rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("logs/ablation"))
    args = parser.parse_args()
    load = os.getloadavg()[0]
    names = rows()
    needed = sorted({n for s in SETTINGS for n in rows_of(s, list(names))})
    jobs = [(index, n) for index, s in enumerate(SETTINGS) for n in rows_of(s, list(names))]
    results: dict[tuple[int, str], dict] = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for done, future in enumerate(as_completed([pool.submit(record, n, names[n], args.out) for n in needed]), 1):
            future.result()
            print(f"recorded {done}/{len(needed)} rows", file=sys.stderr)
        futures = {pool.submit(replay, n, SETTINGS[i], args.out): (i, n) for i, n in jobs}
        for done, future in enumerate(as_completed(futures), 1):
            results[futures[future]] = future.result()
            if done % 20 == 0 or done == len(jobs):
                print(f"{done}/{len(jobs)} runs", file=sys.stderr)
    body, csv_rows = summarise(results)
    with (RESULTS / "hierarchical_ablation.csv").open("w", newline="") as f:
        csv.writer(f).writerows([["item", "setting", "row", *KEYS], *csv_rows])
    text = "\n\n".join([
        f"`nice .venv/bin/python benchmarks/bench_hierarchical_ablation.py` ({len(jobs)} runs on {len(needed)} rows, "
        f"{args.workers} workers, CPU: {cpu_model()}, load average {load:.1f} at the start; every run's numbers in "
        "`hierarchical_ablation.csv`). The frame-level detector (`nordland_hsl`'s `hierarchical_sequence`, "
        "`demo`'s on the demo rows) with one setting changed, on the rows that did not shape that setting "
        "(see the script's docstring): *clean* = the 21 generalisation rows but the whole route and experiments 2 "
        "and 3 (frames 0-2899, ten Nordland chunks, ten synthetic pairs); *realign* = those without frames 0-2899 "
        "and the first chunks of 646 and 200; *jumps* = clean without frames 0-2899 and synthetic world 3 at "
        "night, plus seven held-out jump variants inside Nordland 2900-3575; *demo* = demo worlds 0-4 (streams, "
        "back end left out). Zeta 3. The same table for the detector before three things it found not to pay "
        "were removed (the cut where the route leaves the line, the cut at featureless stretches, screening at "
        "speed 1 alone): [hierarchical_ablation_before.md](hierarchical_ablation_before.md); which rows shaped what, "
        "and what each row of this table decided: docs/results.md.",
        "R@100%P: recall at 100 % precision, mean ± sd (min) over the rows; change: paired difference to the "
        "shipped defaults on the same rows (mean, the worst row, how many rows moved by more than 0.0005); "
        "operating point: the lowest precision over the rows where it accepts anything / the mean recall at the "
        "detector's own threshold; "
        "distances: mean ratio of descriptor distances to the shipped defaults'.",
        table(["item", "setting", "rows", "R@100%P mean ± sd (min)", "change vs shipped", "AUC-PR mean ± sd (min)",
               "ceiling (mean)", "operating point: min precision / mean recall", "distances"], body),
    ])
    publish("hierarchical_ablation", "Frame-level hierarchical detector: each switch and constant ablated on rows "
            "that did not shape it", text)


if __name__ == "__main__":
    main()
