"""``slamfront recipes``, ``slamfront sweeps``, ``slamfront layout``: what slamfront ships.

The files are package data (:mod:`slamfront.resources`), so these work the same from a
source checkout and from an installed wheel, in any directory.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from slamfront.errors import SlamfrontError
from slamfront.resources import LAYOUT, layout_path, shipped_dir, shipped_files


def add_parser(commands: argparse._SubParsersAction) -> None:
    for kind, what, example in (("recipes", "recipe", "run demo"), ("sweeps", "sweep", "sweep synthetic_nn")):
        parser = commands.add_parser(
            kind,
            help=f"list the shipped {what}s",
            description=f"The {what} files shipped with slamfront, with a one-line description. Run one by "
            f"name (`slamfront {example}`); a file of that name in the current directory wins over a shipped one.",
        )
        parser.set_defaults(handler=run_listing, kind=kind, what=what)
    parser = commands.add_parser(
        "layout",
        help="print where a shipped Foxglove layout is (or copy it)",
        description="The Foxglove layouts for run.mcap: in Foxglove, Layouts > Import from file. A run's "
        "report names the one for it: slamfront-layout (loop closure and the back end, a tab each), "
        "slamfront-localization, slamfront-registration.",
    )
    parser.add_argument("name", nargs="?", default=LAYOUT, help=f"the layout's name (default: {LAYOUT})")
    parser.add_argument("-o", "--out", type=Path, help="copy the layout to this file instead")
    parser.set_defaults(handler=run_layout)


def print_listing(paths: list[Path], what: str) -> None:
    """One line per file: its stem and the start of its ``description`` (cut at a word, ~100 characters)."""
    from slamfront.yamlfile import read_yaml_mapping  # PyYAML only: no pydantic, no plugins

    width = max((len(p.stem) for p in paths), default=4)
    for path in paths:
        description = " ".join(str(read_yaml_mapping(path, what).get("description", "")).split())
        if len(description) > 100:  # cut at a word
            description = description[:97].rsplit(" ", 1)[0] + " ..."
        print(f"{path.stem:<{width}}  {description}")


def run_listing(args: argparse.Namespace) -> int:
    paths = shipped_files(args.kind)
    if not paths:  # an installation without its package data: say so, never an empty list
        raise SlamfrontError(
            f"no shipped {args.kind} in {shipped_dir(args.kind)}: this slamfront installation is incomplete; reinstall it"
        )
    print_listing(paths, args.what)
    return 0


def run_layout(args: argparse.Namespace) -> int:
    layout = layout_path(args.name)
    if not layout.is_file():
        raise SlamfrontError(f"{layout}: the shipped Foxglove layout is missing; reinstall slamfront")
    if args.out is None:
        print(layout)
        return 0
    try:
        shutil.copyfile(layout, args.out)
    except OSError as exc:
        raise SlamfrontError(f"{args.out}: cannot write the layout: {exc.strerror or exc}") from exc
    print(args.out)
    return 0
