"""``slamfront recipes``"""

from __future__ import annotations

import argparse


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "recipes", help="list the shipped recipes", description="The recipes in recipes/, with a one-line description."
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from slamfront.recipe import read_recipe_dict, recipes_dir

    paths = sorted(recipes_dir().glob("*.yaml"))
    width = max((len(p.stem) for p in paths), default=4)
    for path in paths:
        description = str(read_recipe_dict(path).get("description", "")).strip().splitlines()
        print(f"{path.stem:<{width}}  {description[0] if description else ''}")
    return 0
