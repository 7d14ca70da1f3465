"""``slamfront retrieval RECIPE [--compare KEY=V1,V2] [-o DIR]``: descriptor retrieval curves."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from slamfront.cli.arguments import frame_count
from slamfront.errors import RecipeError
from slamfront.outputs import folder_lock, write_atomically


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "retrieval",
        help="descriptor retrieval curves (correct reference among the psi nearest), for several settings",
        description=(
            "Run a recipe's source and descriptor only and plot, for psi = 1..K, how often a correct reference "
            "is among each query's psi nearest reference descriptors (Rodrigues 2019 figs 4.1/4.2). --compare "
            "draws one curve per value, e.g. --compare descriptor.params.preprocess=true,false."
        ),
    )
    parser.add_argument("recipe", help="recipe file or shipped recipe name")
    parser.add_argument("-o", "--out", type=Path, help="output folder (default: logs/<recipe>-retrieval/)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a recipe field for every curve (repeatable)")
    parser.add_argument("--compare", metavar="KEY=V1,V2,...", help="one curve per value of this field")
    parser.add_argument("--max-k", type=int, default=20, help="largest psi (default 20)")
    parser.add_argument("--max-frames", type=frame_count, metavar="N", help="only the first N frames of the source")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from slamfront.evaluation.retrieval import descriptor_curve
    from slamfront.report import plots

    if args.max_k < 1:
        raise RecipeError(f"--max-k must be at least 1, got {args.max_k}")
    variants: dict[str, list[str]] = {"recipe": []}
    if args.compare:
        key, sep, values = args.compare.partition("=")
        if not sep or not key or not values:
            raise RecipeError(f"--compare {args.compare!r}: expected KEY=V1,V2,...")
        variants = {f"{key.split('.')[-1]}={value}": [f"{key}={value}"] for value in values.split(",")}
    curves = {
        label: descriptor_curve(args.recipe, [*args.overrides, *extra], args.max_k, args.max_frames, label)
        for label, extra in variants.items()
    }
    out = args.out or Path("logs") / f"{Path(args.recipe).stem}-retrieval"
    ks = np.arange(1, args.max_k + 1)
    header = "| psi | " + " | ".join(curves) + " |"
    rows = [f"| {k} | " + " | ".join(f"{curve[k - 1]:.4f}" for curve in curves.values()) + " |" for k in ks]
    table = "\n".join([header, "|" + " --- |" * (len(curves) + 1), *rows])
    with folder_lock(out, "retrieval"):  # one writer per folder: never a mix of two studies' files
        figure = plots.recall_curves({label: (ks, curve) for label, curve in curves.items()}, out / "retrieval.png",
                                     title="correct reference among the psi nearest descriptors")
        write_atomically(out / "retrieval.md", f"# Descriptor retrieval: {args.recipe}\n\n{table}\n\n![retrieval](retrieval.png)\n")
        write_atomically(out / "retrieval.json", json.dumps({k: [float(v) for v in c] for k, c in curves.items()}, indent=2) + "\n")
    print(table)
    print(f"plot:  {figure}")
    return 0
