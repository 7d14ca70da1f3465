"""``slamfront datasets [list | path [NAME] | download NAME | fetch [NAME ...] [--for-tests]]``.

``download`` fetches a public dataset a source plugin declares (an archive from its
publisher); ``fetch`` fetches the pinned datasets of the manifest (the real data the
tests read) file by file, verified against their SHA-256. Where data lives is the rule
of :mod:`slamfront.data`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from slamfront.data import DATA_ENV, MIRROR_ENV, data_root, download_root
from slamfront.errors import DataError

if TYPE_CHECKING:  # the rest is imported when the command runs: its parser stays light
    from slamfront.datasets import DatasetDownload
    from slamfront.manifest import PinnedDataset, PinnedFile


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "datasets",
        help="list, locate, download and fetch the real datasets",
        description=(
            "The real datasets: `list` shows the public datasets the installed sources read and the pinned "
            "datasets the tests read; `path` prints the data root (or where NAME is); `download NAME` fetches "
            "a source's dataset (official URL, resumable, checksum); `fetch --for-tests` fetches the pinned "
            "datasets missing from the data root, file by file, each checked against its SHA-256. "
            f"The data root is ${DATA_ENV}, else shared/data beside a source checkout, else the per-user data "
            f"directory (~/.local/share/slamfront on Linux); downloads go to ${DATA_ENV}, else the per-user data "
            "directory. `slamfront datasets path` prints the data root, `slamfront datasets` both folders."
        ),
    )
    parser.add_argument(
        "action", nargs="?", choices=("list", "path", "download", "fetch"), default="list",
        help="list: every dataset and whether it is here (default); path [NAME]: print the data root, or "
        "where NAME is read from; download NAME: fetch a source's dataset; fetch --for-tests: fetch the "
        "pinned datasets the tests read",
    )
    parser.add_argument("names", nargs="*", metavar="NAME", help="dataset name(s)")
    parser.add_argument("--for-tests", action="store_true", help="fetch: every pinned dataset the tests read")
    parser.add_argument(
        "--url", help=f"download: from this URL instead (a mirror, or file:///path/to/archive); fetch: a mirror "
        f"base URL serving a copy of a data root, <URL>/<folder>/<file> (default: ${MIRROR_ENV}, else the origins)",
    )
    parser.add_argument("--dir", type=Path, help="download folder for `download` (default: the download root)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


DATASETS_GROUP = "slamfront.datasets"
"""The entry-point group listing the public datasets of installed sources (see pyproject.toml)."""


def catalogue() -> dict[str, tuple[str, DatasetDownload]]:
    """Every dataset the installed sources declare: ``{name: (source plugin, download)}``.

    Read from the ``slamfront.datasets`` entry-point group, whose modules hold only the
    records: listing them imports no source. A module that cannot be imported is one
    warning line naming it; the others are still listed.
    """
    import importlib

    found: dict[str, tuple[str, DatasetDownload]] = {}
    for name, value, owner in _dataset_entry_points():
        try:
            module, _, attribute = value.partition(":")  # `module` (its DOWNLOADS) or `module:mapping`
            declared = getattr(importlib.import_module(module), attribute.strip() or "DOWNLOADS")
        except Exception as exc:  # noqa: BLE001 - a broken third-party module must not hide the others
            print(f"slamfront: warning: {DATASETS_GROUP} entry point {name!r} of {owner} ({value}) "
                  f"cannot be read: {type(exc).__name__}: {exc}", file=sys.stderr)
            continue
        for source, downloads in declared.items():
            for spec in downloads:
                found[spec.name] = (source, spec)
    return found


def _dataset_entry_points() -> list[tuple[str, str, str]]:
    """(name, value, distribution) of each entry point of the group.

    Read from the ``entry_points.txt`` of the distributions on ``sys.path`` (what
    :mod:`importlib.metadata` reads too), because importing that module costs as much as
    starting Python; through it when the scan finds none (an unusual installation).
    """
    import configparser

    points = []
    for folder in dict.fromkeys(sys.path):
        try:
            entries = [e for e in os.scandir(folder or ".") if e.name.endswith((".dist-info", ".egg-info"))]
        except OSError:
            continue
        for entry in entries:
            text = Path(entry.path, "entry_points.txt")
            if not text.is_file() or f"[{DATASETS_GROUP}]" not in (content := text.read_text(errors="replace")):
                continue
            parser = configparser.ConfigParser(delimiters=("=",), interpolation=None)
            parser.optionxform = str  # type: ignore[assignment,method-assign]
            parser.read_string(content)
            owner = entry.name.rsplit(".", 1)[0].replace("-", " ", 1)
            points += [(name, value.strip(), owner) for name, value in parser.items(DATASETS_GROUP)]
    if points:
        return points
    from importlib.metadata import entry_points

    return [(e.name, e.value, f"{e.dist.name} {e.dist.version}" if e.dist else "?") for e in
            entry_points(group=DATASETS_GROUP)]


def run(args: argparse.Namespace) -> int:
    if args.action == "fetch":
        return _fetch(args)
    if args.action == "path" and not args.names:
        print(data_root())
        return 0
    from slamfront.datasets import fetch

    datasets = catalogue()
    into = args.dir or download_root()
    if args.action == "list":
        return _list(datasets, into)
    if len(args.names) != 1:
        raise DataError(f"`slamfront datasets {args.action}` needs one dataset name: {', '.join(sorted(datasets))}")
    name = args.names[0]
    if name not in datasets:
        from slamfront.suggest import did_you_mean

        raise DataError(f"unknown dataset {name!r}; {did_you_mean(name, datasets, 'datasets')}")
    source, spec = datasets[name]
    if args.action == "path":
        shared = data_root() / name
        print(shared if shared.is_dir() and args.dir is None else spec.folder(into))
        return 0
    folder = fetch(spec, into, url=args.url, progress=False if args.quiet else None)
    print(f"{spec.name}: {folder} (read it with the {source!r} source)")
    return 0


def _list(datasets: dict[str, tuple[str, DatasetDownload]], into: Path) -> int:
    from slamfront.manifest import dataset_summaries

    width = max((len(n) for n in datasets), default=4)
    print("Public datasets the sources read (`slamfront datasets download NAME`):")
    for name, (source, spec) in sorted(datasets.items()):
        if spec.is_installed(into):
            state = "downloaded"
        elif (data_root() / name).is_dir():
            state = "in data root"
        else:
            state = "manual download" if spec.url is None else "not downloaded"
        print(f"  {name:<{width}}  source: {source:<14} {state:<15} {spec.title}")
    pinned = dataset_summaries()
    width = max(len(name) for name, *_ in pinned)
    print("\nPinned datasets the tests read (`slamfront datasets fetch --for-tests`):")
    for name, folder, _, size, licence in pinned:
        print(f"  {name:<{width}}  {folder:<28} {size / 1e6:6.1f} MB  {licence}")
    print(f"\ndata root: {data_root()}\ndownloads: {into}")
    return 0


def _fetch(args: argparse.Namespace) -> int:
    from slamfront.manifest import load_manifest

    pinned = {d.name: d for d in load_manifest()}
    if args.for_tests == bool(args.names):
        raise DataError(f"`slamfront datasets fetch` needs --for-tests or pinned dataset names: {', '.join(pinned)}")
    unknown = [n for n in args.names if n not in pinned]
    if unknown:
        raise DataError(f"unknown pinned dataset {unknown[0]!r}; known: {', '.join(pinned)}")
    chosen = list(pinned.values()) if args.for_tests else [pinned[n] for n in args.names]
    root = data_root()
    damaged = {d.name: d.damaged(root) for d in chosen}
    todo = [d for d in chosen if damaged[d.name]]
    n_files = sum(len(d.files) for d in chosen)
    if not todo:
        print(f"test data: {n_files} files of {len(chosen)} datasets present and verified in {root}")
        return 0
    if root != download_root():
        raise DataError(
            f"{root}: {sum(len(v) for v in damaged.values())} pinned files are missing or differ "
            f"({', '.join(d.name for d in todo)}); this folder beside the checkout is read, never written: "
            f"set {DATA_ENV}=DIR to fetch into DIR"
        )
    mirror = args.url or os.environ.get(MIRROR_ENV) or None
    failed = _fetch_each(todo, damaged, root, mirror, progress=False if args.quiet else None)
    if failed:
        raise DataError(
            f"{len(failed)} of {len(chosen)} pinned datasets are incomplete in {root}: put the files named above "
            f"there by hand (as <folder>/<file>), or give a mirror with --url BASE or ${MIRROR_ENV}; "
            "then run the same command again (what is already fetched is kept)"
        )
    print(f"test data: {n_files} files of {len(chosen)} datasets present and verified in {root}")
    return 0


def _fetch_each(
    todo: list[PinnedDataset], damaged: dict[str, list[PinnedFile]], root: Path, mirror: str | None,
    progress: bool | None,
) -> list[str]:
    """Fetch each dataset; one line on stderr for each that fails. Once a host is unreachable
    (offline), the rest are listed without trying, so offline costs no time-outs."""
    from slamfront.datasets import UnreachableError
    from slamfront.manifest import fetch_dataset

    failed: list[str] = []
    offline: str | None = None
    for dataset in todo:
        missing = damaged[dataset.name]
        where = mirror or dataset.origin
        line = (f"{dataset.name}: {len(missing)} of {len(dataset.files)} files ({sum(f.size for f in missing) / 1e6:.1f} MB) "
                f"missing or damaged in {root / dataset.folder}; get them from {where}")
        if offline is not None:
            print(f"{line} ({offline})", file=sys.stderr)
            failed.append(dataset.name)
            continue
        try:
            fetch_dataset(dataset, root, mirror, progress=progress)
        except UnreachableError as exc:
            cause = exc.__cause__
            offline = f"unreachable: {getattr(cause, 'reason', cause) or exc}"
            print(f"{line} ({offline})", file=sys.stderr)
            failed.append(dataset.name)
        except DataError as exc:
            print(f"{line} ({exc})", file=sys.stderr)
            failed.append(dataset.name)
    return failed
