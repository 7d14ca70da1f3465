"""Jumps in the map, on held-out data: Rodrigues 2019's experiments 2 and 3 built inside the
Nordland frames 2900-3575 (the section the detector's defaults were chosen on, in no
reported row but the whole route's).

A block of the summer reference is moved to the end (``reordered``: the winter queries'
route jumps in the map at the block's edges) or replaced by other frames (``replaced``:
the block's queries have no true match). For each variant, the frame-level detector with its
shipped defaults and with the line check made for jumps switched off (``line_check``; its
companion, the cut where the route leaves the line, was removed when the ablation in
hierarchical_ablation_before.md found it paying nowhere): recall at 100 % precision
against the correct-answer ceiling.

The *design* variants are the four the checks were worked out on; the *test* variants were
added afterwards and run once, after the design was fixed.

Run: nice .venv/bin/python benchmarks/bench_hierarchical_jumps.py [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402

QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
DESIGN = [("reordered", 200, 150), ("reordered", 350, 150), ("replaced", 200, 150), ("replaced", 350, 150)]
TEST = [(experiment, start, length) for experiment in ("reordered", "replaced")
        for start, length in ((100, 100), (300, 100), (450, 150), (250, 200))]
WITHOUT = ["loop_detector.params.line_check=false"]


def run(variant: tuple[str, int, int], without: bool, scratch: str) -> dict:
    experiment, start, length = variant
    overrides = [*QUICK, "source.params.start=2900", f"source.params.experiment={experiment}",
                 f"source.params.block_start={start}", f"source.params.block_length={length}",
                 *(WITHOUT if without else [])]
    loaded, path = load_recipe("nordland_hsl", overrides)
    out = Path(scratch) / f"{experiment}_{start}_{length}_{'without' if without else 'shipped'}"
    return run_pipeline(build_pipeline(loaded, str(path)), str(path), out, progress=False).metrics


def rows(variants: list[tuple[str, int, int]], results: dict) -> tuple[list[list[object]], list[float], list[float]]:
    out, shipped, without = [], [], []
    for variant in variants:
        a, b = results[(variant, False)], results[(variant, True)]
        experiment, start, length = variant
        out.append([f"{experiment}, frames {start}-{start + length - 1}", round(b["recall_at_100p"], 3),
                    round(a["recall_at_100p"], 3), round(a["correct_answer_ceiling"], 3), round(a["auc_pr"], 3),
                    operating_point(a)])
        shipped.append(a["recall_at_100p"])
        without.append(b["recall_at_100p"])
    return out, shipped, without


def operating_point(metrics: dict) -> str:
    """Precision / recall at the detector's own threshold (answers accepted), **below 95 %** marked."""
    accepted = int(metrics.get("n_accepted", 0))
    if not accepted:
        return "accepts nothing"
    precision = float(metrics["precision_at_operating_point"])
    text = f"{precision:.3f} / {float(metrics['recall_at_operating_point']):.3f} ({accepted})"
    return f"**{text}**" if precision < 0.95 else text


def spread(values: list[float]) -> str:
    return f"{np.mean(values):.3f} ± {np.std(values, ddof=1):.3f} (min {min(values):.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    jobs = [(variant, without) for variant in DESIGN + TEST for without in (False, True)]
    with tempfile.TemporaryDirectory() as scratch, ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(run, job[0], job[1], scratch): job for job in jobs}
        results = {}
        for done, future in enumerate(as_completed(futures), 1):  # progress: the runs take minutes
            results[futures[future]] = future.result()
            print(f"{done}/{len(jobs)} runs", file=sys.stderr)
    headers = ["block", "R@100%P without the line check", "R@100%P shipped", "correct-answer ceiling", "AUC-PR shipped",
               "shipped, at its operating point: precision / recall (accepted)"]
    sections = [
        f"`nice .venv/bin/python benchmarks/bench_hierarchical_jumps.py` (load average {load:.1f} at the start). "
        "Nordland frames 2900-3575 (676 summer references, 676 winter queries), zeta = 3, frame-level detector "
        "(`nordland_hsl`) with its shipped defaults, and with `line_check: false`. The last column is what the "
        "shipped detector accepts at its own threshold (`accept: auto`); bold: less than 95 % of it right.",
    ]
    for title, variants in (("Design variants (the checks were worked out on these)", DESIGN),
                            ("Test variants (added after the design was fixed; none shaped it)", TEST)):
        body, shipped, without = rows(variants, results)
        sections.append(f"## {title}\n\n" + table(headers, body)
                        + f"\n\nR@100%P mean ± sd: without the line check {spread(without)}; shipped {spread(shipped)}.")
    publish("hierarchical_jumps", "Hierarchical detector: jumps in the map (held-out Nordland 2900-3575)",
            "\n\n".join(sections))


if __name__ == "__main__":
    main()
