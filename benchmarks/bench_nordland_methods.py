"""SeqSLAM vs the hierarchical detector on the whole Nordland route, in one benchmark run.

Each method runs in its own child process (so its peak memory is its own), one after
the other: the whole recipe (reading 7,152 frames, describing, matching, evaluating,
logging), then the detector alone is characterised by its searches. Ratios are against
the hierarchical detector measured in the same run.

Run: .venv/bin/python benchmarks/bench_nordland_methods.py [RECIPE[@key=value,...] ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

DEFAULT = [
    "nordland_hsl",
    "nordland_seqslam",
    "nordland_seqslam_fast",
    "nordland_seqslam_fast@loop_detector.params.knn=hnsw",
    "nordland_seqslam_fast@loop_detector.params.anchor=middle",
    "nordland_openseqslam",
]
"""Recipes, each optionally with ``@key=value,key=value`` overrides."""

CHILD = """
import json, resource, sys
from pathlib import Path
from slamfront.recipe import build_pipeline, load_recipe
from slamfront.runtime import run_pipeline
name, _, overrides = sys.argv[1].partition("@")
recipe, path = load_recipe(name, [o for o in overrides.split(",") if o])
result = run_pipeline(build_pipeline(recipe, str(path)), str(path), Path(sys.argv[2]), progress=False)
m = result.metrics
print(json.dumps({k: m.get(k) for k in ("seconds", "frames_per_second", "n_searches", "recall_at_100p", "auc_pr",
                  "n_places_reference", "n_places_query")} | {"timing": m["timing"],
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("recipes", nargs="*", default=DEFAULT)
    args = parser.parse_args()
    measured = {}
    for name in args.recipes:
        with tempfile.TemporaryDirectory() as out:
            done = subprocess.run([sys.executable, "-c", CHILD, name, out], capture_output=True, text=True, check=True)
        measured[name] = json.loads(done.stdout.strip().splitlines()[-1])
        print(name, measured[name]["seconds"], flush=True)
    base = measured[args.recipes[0]]
    rows = []
    for name, m in measured.items():
        detector = m["timing"].get("loop_detector", {})
        rows.append([
            name, m["seconds"], m["frames_per_second"], m["seconds"] / base["seconds"], m["peak_mb"],
            m["n_searches"], detector.get("total_s", 0.0), m["recall_at_100p"], m["auc_pr"],
        ])
    body = "\n\n".join([
        f"Whole Nordland route (3,576 summer reference + 3,576 winter query frames, 64x32), each recipe "
        f"in its own process, one after the other; ratios against `{args.recipes[0]}` in this run.",
        table(["recipe", "seconds", "frames/s", "time vs first", "peak RSS MB", "searches",
               "detector s (process + finish)", "recall@100%P", "AUC-PR"], rows),
        "SeqSLAM answers every query but the first and last ds/2 with a full search over all "
        "references; the hierarchical detector searches once per completed query sequence of rho places.",
    ])
    publish("nordland_methods", "SeqSLAM vs the hierarchical detector on Nordland", body)


if __name__ == "__main__":
    main()
