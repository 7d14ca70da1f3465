"""The place map's index on the shipped data: the default (``search: auto``) against the
VP-tree and brute force, whole runs of the hierarchical recipes, interleaved (A B C A B C).

Each setting runs the same recipe; the answers must not change (exact search either way:
the loop results are compared message for message), only the time of the stages that
search the place map (the place map and the detector, which queries it). ``auto`` keeps
brute force below 10,000 places and tries a VP-tree above (``slamfront.core.vptree``).

Run: .venv/bin/python benchmarks/bench_place_search.py [RECIPE ...] [--repeat 2]
(default: nordland_hsl synthetic_hsl demo). Writes results/place_search.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_logging import machine  # noqa: E402
from common import publish, table  # noqa: E402

from slamfront.mcaplog.diff import diff_logs  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import RunResult, run_pipeline  # noqa: E402

MODES = ("auto", "vptree", "brute_force")
SEARCHING = ("place_map", "loop_detector")


def run(recipe: str, mode: str, out: Path) -> RunResult:
    loaded, path = load_recipe(recipe, [f"place_map.params.search={mode}", "log.images=false", "log.scene=false"])
    return run_pipeline(build_pipeline(loaded, str(path)), str(path), out, progress=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recipes", nargs="*", default=["nordland_hsl", "synthetic_hsl", "demo"])
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for recipe in args.recipes:
            seconds: dict[str, list[float]] = {mode: [] for mode in MODES}
            logs: dict[str, Path] = {}
            places = 0
            for repeat in range(args.repeat):
                for mode in MODES:
                    result = run(recipe, mode, Path(scratch) / f"{recipe}_{mode}_{repeat}")
                    timing = result.metrics["timing"]
                    seconds[mode].append(sum(timing[k]["total_s"] for k in SEARCHING if k in timing))
                    logs.setdefault(mode, result.log_path)
                    places = result.metrics.get("n_places_reference", places)
            same = all(
                diff_logs(logs["auto"], logs[mode], ignore=["/metrics", "/*/stage_statistics"]).identical
                for mode in MODES[1:]
            )
            auto = statistics.median(seconds["auto"])
            for mode in MODES:
                median = statistics.median(seconds[mode])
                rows.append([recipe, places, mode, median, median / auto, "yes" if same else "NO"])
            print(table(["recipe", "places", "search", "s", "vs auto", "same answers"], rows[-3:]), flush=True)
    body = (
        f"Machine: {machine()}, shared with other work. Each recipe runs once per setting per repeat "
        f"({args.repeat} repeats, interleaved); `s` is the median wall time of the stages that search the place "
        "map (place map + loop detector, from `metrics.json` timing), `vs auto` the ratio to the default in the "
        "same rounds. `same answers`: every loop result and place assignment of the run equals the default's "
        "(`slamfront diff`, counters left out). Below 10,000 places `auto` runs brute force itself (no tree is "
        "tried), so the gap between those two rows is the run-to-run noise of a shared machine.\n\n"
        + table(["recipe", "places (reference)", "search", "s", "vs auto", "same answers"], rows)
    )
    publish("place_search", "Place search on the shipped data: default vs VP-tree vs brute force", body)


if __name__ == "__main__":
    main()
