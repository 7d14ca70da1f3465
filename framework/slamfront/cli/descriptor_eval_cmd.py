"""``slamfront eval descriptors SOURCE``: Barbosa 2017's descriptor tests (chapter 5.1) with a report."""

from __future__ import annotations

import argparse
import itertools
import json
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.errors import DataError, PluginError
from slamfront.outputs import folder_lock, write_atomically

if TYPE_CHECKING:
    import numpy as np

    from slamfront.descriptor_eval import DescriptorChoice, DescriptorEvaluation

# Barbosa 2017, tables 3 and 4 (TUM RGB-D fr2/pioneer_slam, OpenCV 3.0, SURF included)
PUBLISHED = {
    "brief": (62.14, 292.7262),
    "brisk": (19.48, 140.3895),
    "freak": (82.86, 247.8211),
    "orb": (34.71, 385.0895),
    "sift": (152.45, 613.5436),
    "surf": (20.19, 182.8157),
}


def add_parser(tools: argparse._SubParsersAction) -> None:
    parser = tools.add_parser(
        "descriptors",
        help="Barbosa 2017's descriptor tests: local, global (top-5), matching speed, dissimilarity",
        description=(
            "Run the descriptor tests of Barbosa 2017, chapter 5.1, on an image sequence: SOURCE is a folder of "
            "images (natural name order; relative paths also under the data root) or a recipe whose source "
            "gives the frames (e.g. a synthetic world). Writes report.md, metrics.json and plots."
        ),
    )
    parser.add_argument("source", metavar="SOURCE", help="image folder, or a recipe file / shipped recipe name")
    parser.add_argument("--descriptors", default="orb,brisk,akaze,sift,brief,freak",
                        help="comma-separated; name+detector for BRIEF/FREAK (default: on SIFT keypoints, as the paper)")
    parser.add_argument("--targets", type=int, default=16,
                        help="target frames drawn at random (default 16, as Barbosa 2017)")
    parser.add_argument("--target", type=int, action="append", default=[], metavar="FRAME",
                        help="test this frame (0-based; repeatable; replaces the random draw)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random draw")
    parser.add_argument("--neighbours", type=int, default=10, help="local test: frames either side (default 10)")
    parser.add_argument("--top", type=int, default=5, help="global test: most similar frames listed (default 5)")
    parser.add_argument("--max-features", type=int, default=1000, help="keypoints per frame (default 1000)")
    parser.add_argument("--geometry", choices=("fundamental", "homography", "none"), default="fundamental",
                        help="RANSAC model that verifies the matches (default fundamental)")
    parser.add_argument("--step", type=int, default=1, help="use every step-th frame")
    parser.add_argument("--limit", type=int, help="use at most this many frames")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default logs/descriptor_eval/<source>)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def parse_choices(text: str) -> list[DescriptorChoice]:
    """``--descriptors`` as choices, refusing unknown names (and SURF, with the reason)."""
    from slamfront.descriptor_eval import DescriptorChoice
    from slamfront.local_features import DESCRIPTORS, DETECTORS, SURF_UNAVAILABLE

    choices = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        choice = DescriptorChoice.parse(item)
        if choice.descriptor == "surf":
            raise PluginError(f"--descriptors: {SURF_UNAVAILABLE}")
        if choice.descriptor not in DESCRIPTORS:
            raise PluginError(f"--descriptors: unknown descriptor {choice.descriptor!r}; one of {', '.join(DESCRIPTORS)}")
        if choice.detector != "native" and choice.detector not in DETECTORS:
            raise PluginError(f"--descriptors: unknown detector {choice.detector!r}; one of {', '.join(DETECTORS)}")
        choices.append(choice)
    if not choices:
        raise PluginError("--descriptors: name at least one descriptor")
    return choices


def frames_of(source: str, step: int, limit: int | None) -> tuple[str, Iterator[tuple[str, np.ndarray]]]:
    """A label and the (name, grey image) pairs of a folder or of a recipe's source."""
    from slamfront.data import data_root
    from slamfront.imageio import list_images, read_image

    folder = Path(source)
    if not folder.is_dir() and not folder.is_absolute() and (data_root() / folder).is_dir():
        folder = data_root() / folder
    if folder.is_dir():
        files = list_images(folder)[::step][:limit]
        return folder.name, ((path.name, read_image(path, "gray")) for path in files)
    from slamfront.recipe import build_pipeline, load_recipe

    recipe, path = load_recipe(source)
    frames = build_pipeline(recipe, str(path)).source.frames()
    chosen = itertools.islice(frames, 0, None if limit is None else limit * step, step)
    return recipe.name, ((frame.name or str(frame.index), frame.gray()) for frame in chosen)


def run(args: argparse.Namespace) -> int:
    from slamfront.descriptor_eval import evaluate_descriptors
    from slamfront.matching import MatchingConfig

    choices = parse_choices(args.descriptors)
    for name, value in (("--step", args.step), ("--neighbours", args.neighbours), ("--top", args.top),
                        ("--max-features", args.max_features), ("--targets", args.targets)):
        if value < 1:
            raise PluginError(f"{name}: must be at least 1, got {value}")
    label, images = frames_of(args.source, args.step, args.limit)
    try:
        study = evaluate_descriptors(
            images, choices, args.targets, args.target, args.neighbours, args.top, args.max_features,
            MatchingConfig(geometry=args.geometry), args.seed, progress=not args.quiet,
        )
    except ValueError as exc:
        raise DataError(f"{args.source}: {exc}") from None
    out = args.out or Path("logs") / "descriptor_eval" / label
    metrics = {"source": args.source, "n_frames": study.n_frames, "targets": study.targets, **_tables(study)}
    with folder_lock(out, "eval descriptors"):  # one writer per folder: never a mix of two studies' files
        figures = _plots(study, out)
        write_atomically(out / "metrics.json", json.dumps(metrics, indent=2, default=_plain, allow_nan=False) + "\n")
        write_atomically(out / "report.md", _report(study, args.source, figures))
    if args.json:
        print(json.dumps(metrics, indent=2, default=_plain))
    else:
        print(_summary_table(study))
        print(f"\nreport:  {out / 'report.md'}")
    return 0


def _tables(study: DescriptorEvaluation) -> dict[str, object]:
    import numpy as np

    return {
        "summary": study.summary(),
        "global_test": {r.label: {str(t): r.top[t] for t in study.targets} for r in study.results},
        "local_test": {
            r.label: {str(t): [v if np.isfinite(v) else None for v in r.local[t].tolist()] for t in study.targets}
            for r in study.results
        },
    }


def _summary_table(study: DescriptorEvaluation) -> str:
    lines = [
        "| descriptor | keypoints/frame | extract ms | match ms (table 3) | dissimilarity (table 4) "
        f"| top-{study.top} within ±{study.neighbours} | distance threshold |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for label, row in study.summary().items():
        lines.append(
            f"| {label} | {row['keypoints_mean']:.0f} | {row['extract_ms']:.1f} | {row['match_ms']:.2f} "
            f"| {row['dissimilarity']:.1f} | {row['top_near_fraction']:.0%} | {row['max_distance']:g} |"
        )
    return "\n".join(lines)


def _report(study: DescriptorEvaluation, source: str, figures: list[str]) -> str:
    targets = ", ".join(f"{t} (`{study.names[t]}`)" for t in study.targets)
    parts = [
        f"# Descriptor evaluation: {source}",
        f"{study.n_frames} frames. Target frames (0-based): {targets}. Local test ±{study.neighbours} frames; "
        f"global test top {study.top}. Matching as Barbosa 2017 §4.1.2: brute force, distance threshold, RANSAC; "
        "a match count is the number of RANSAC inliers.",
        "## Speed and dissimilarity (tables 3 and 4)",
        _summary_table(study),
        "Published (Barbosa 2017, TUM RGB-D fr2/pioneer_slam, another machine and OpenCV 3.0; different data):\n\n"
        "| descriptor | match ms (table 3) | dissimilarity (table 4) |\n| --- | --- | --- |\n"
        + "\n".join(f"| {name} | {ms} | {dis} |" for name, (ms, dis) in PUBLISHED.items()),
        f"## Global test (tables 1 and 2): the {study.top} most similar frames, Q/C = frame/matches",
    ]
    for target in study.targets:
        header = "| descriptor | " + " | ".join("Q/C" for _ in range(study.top)) + " |"
        rows = [header, "|" + " --- |" * (study.top + 1)]
        for r in study.results:
            rows.append(f"| {r.label} | " + " | ".join(f"{q}/{c}" for q, c in r.top[target]) + " |")
        parts += [f"Target frame {target}:", "\n".join(rows)]
    parts += ["## Local test (figures 36 and 37)", *(f"![{f}]({f})" for f in figures)]
    return "\n\n".join(parts) + "\n"


def _plots(study: DescriptorEvaluation, out: Path) -> list[str]:
    import numpy as np

    from slamfront.report import plots

    offsets = np.arange(-study.neighbours, study.neighbours + 1)
    local = plots.local_test(offsets, {r.label: r.local for r in study.results}, out / "local_test.png",
                             "local test: matches with neighbouring frames")
    distances = plots.distance_histograms(
        {r.label: (r.verified_distances, r.unrelated_distances, r.max_distance) for r in study.results},
        out / "distances.png", "distances: ratio-tested RANSAC matches (±3 frames) vs nearest neighbours in the 5 least similar frames",
    )
    return [local.name, distances.name]


def _plain(value: object) -> object:
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value).__name__)
