"""Choose the place threshold nu of the ``hierarchical`` place map from a reference traversal alone.

Rodrigues 2019 leaves nu open. We pick it without looking at any query: run the recipe's
source and descriptor over the *reference* frames only and take the nu whose places
hold, on average, as many frames as Rodrigues 2019's own maps did (Table 4.4: GPW 200 frames
in 112 places, UofA 646 in 236, i.e. 1.79 and 2.74 frames per place; mean 2.26). A
single stream (a SLAM run) has no reference traversal: ``--first N`` takes its first N
frames instead, before any revisit.

    .venv/bin/python scripts/choose_place_threshold.py recipes/nordland_hsl.yaml
    .venv/bin/python scripts/choose_place_threshold.py recipes/synthetic_hsl.yaml --frames-per-place 2.26
    .venv/bin/python scripts/choose_place_threshold.py recipes/demo.yaml --first 100
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from slamfront.plugin import StageInputs
from slamfront.recipe import build_pipeline, load_recipe
from slamfront_plugins.place_maps.hierarchical import choose_similarity_threshold, place_sizes

SEED_FRAMES_PER_PLACE = (200 / 112 + 646 / 236) / 2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recipe")
    parser.add_argument("--frames-per-place", type=float, default=SEED_FRAMES_PER_PLACE)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--first", type=int, metavar="N",
                        help="use the first N frames of a stream (which has no reference traversal)")
    args = parser.parse_args()
    recipe, path = load_recipe(args.recipe, args.overrides)
    pipeline = build_pipeline(recipe, str(path))
    descriptor = pipeline.plugins["descriptor"]
    place_map = pipeline.plugins.get("place_map")
    max_distance = getattr(getattr(place_map, "config", None), "max_distance", 2.0)
    vectors, metric = [], "l1"
    for frame in tqdm(pipeline.source.frames(), desc="reference frames", unit="frame", total=args.first):
        if len(vectors) == args.first or (args.first is None and frame.traversal != "reference"):
            break
        features = descriptor.process(StageInputs(frame=frame))[0]
        vectors.append(features.vector)
        metric = features.metric
    if not vectors:
        parser.error("the source gives no reference traversal: use --first N for a stream")
    reference = np.stack(vectors)
    nu = choose_similarity_threshold(reference, args.frames_per_place, max_distance, metric)
    what = f"first {len(reference)} frames" if args.first else f"{len(reference)} reference frames"
    print(f"{what}; target {args.frames_per_place:.2f} frames per place")
    print("| nu | places | frames per place |")
    print("| --- | --- | --- |")
    for candidate in np.round(nu + np.arange(-0.02, 0.0201, 0.005), 3):
        sizes = place_sizes(reference, float(candidate), max_distance, metric)
        mark = " (chosen)" if abs(candidate - nu) < 1e-9 else ""
        print(f"| {candidate:.3f}{mark} | {len(sizes)} | {sizes.mean():.2f} |")
    print(f"\nplace_map.params.similarity_threshold: {nu}")


if __name__ == "__main__":
    main()
