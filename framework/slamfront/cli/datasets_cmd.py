"""``slamfront datasets [list | download NAME | path NAME]``: the public datasets sources can read."""

from __future__ import annotations

import argparse
from pathlib import Path

from slamfront.data import cache_root, data_root
from slamfront.datasets import DatasetDownload, fetch
from slamfront.errors import DataError
from slamfront.registry import PluginRegistry
from slamfront.suggest import did_you_mean


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "datasets",
        help="list the public datasets and download one into the cache",
        description=(
            "Public datasets the installed source plugins read. `download NAME` fetches one (official URL, "
            "resumable, checksum) into $SLAMFRONT_CACHE or ~/.cache/slamfront and extracts it there."
        ),
    )
    parser.add_argument(
        "action", nargs="?", choices=("list", "download", "path"), default="list",
        help="list: every dataset and whether it is here (default); download NAME: fetch it into the "
        "cache; path NAME: print the folder a source reads it from",
    )
    parser.add_argument("name", nargs="?", help="dataset name (download, path)")
    parser.add_argument("--url", help="download from this URL instead (a mirror, or file:///path/to/archive)")
    parser.add_argument("--cache", type=Path, help="cache folder (default: $SLAMFRONT_CACHE or ~/.cache/slamfront)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def catalogue(registry: PluginRegistry | None = None) -> dict[str, tuple[str, DatasetDownload]]:
    """Every dataset the installed sources declare: ``{name: (source plugin, download)}``."""
    found: dict[str, tuple[str, DatasetDownload]] = {}
    for info in (registry or PluginRegistry()).all("source"):
        for spec in getattr(info.cls, "downloads", ()):
            found[spec.name] = (info.name, spec)
    return found


def run(args: argparse.Namespace) -> int:
    datasets = catalogue()
    cache = args.cache or cache_root()
    if args.action == "list":
        width = max((len(n) for n in datasets), default=4)
        for name, (source, spec) in sorted(datasets.items()):
            if spec.is_installed(cache):
                state = "downloaded"
            elif (data_root() / name).is_dir():
                state = "in data root"
            else:
                state = "manual download" if spec.url is None else "not downloaded"
            print(f"{name:<{width}}  source: {source:<14} {state:<15} {spec.title}")
        print(f"\ncache: {cache}")
        return 0
    if not args.name:
        raise DataError(f"`slamfront datasets {args.action}` needs a dataset name: {', '.join(sorted(datasets))}")
    if args.name not in datasets:
        raise DataError(f"unknown dataset {args.name!r}; {did_you_mean(args.name, datasets, 'datasets')}")
    source, spec = datasets[args.name]
    if args.action == "path":
        print(spec.folder(cache))
        return 0
    folder = fetch(spec, cache, url=args.url, progress=False if args.quiet else None)
    print(f"{spec.name}: {folder} (read it with the {source!r} source)")
    return 0
