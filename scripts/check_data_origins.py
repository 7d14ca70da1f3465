"""Check that every origin in the data manifest still serves its files, byte for byte (for maintainers).

``slamfront datasets fetch`` trusts the manifest's origins; this checks them. Every pinned
file is downloaded from its origin (never a mirror) into a temporary folder and compared
with the manifest's size and SHA-256; a release archive is downloaded once and its
members are checked. One line per dataset: ``ok``, or which files are absent at the
origin (an HTTP error, e.g. the pinned commit lacks them) and which differ.

Run: .venv/bin/python scripts/check_data_origins.py [NAME ...]
Exit 0: every origin holds its files; 1: some do not; 2: no network (one line, nothing checked).
"""

from __future__ import annotations

import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from urllib.parse import urlparse

from slamfront.datasets import UnreachableError, download, sha256_of
from slamfront.errors import DataError
from slamfront.manifest import PARALLEL, PinnedDataset, PinnedFile, fetch_dataset, load_manifest


def _check_file(dataset: PinnedDataset, file: PinnedFile, folder: Path) -> str | None:
    """None when the origin serves ``file`` as pinned, else what is wrong with it."""
    target = folder / file.path
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        download(dataset.url(file), target, dataset.name, retry="python scripts/check_data_origins.py")
    except UnreachableError:
        raise
    except DataError as exc:
        return f"{file.path}: absent ({str(exc).rsplit(': ', 1)[-1]})"
    size, digest = target.stat().st_size, sha256_of(target)
    target.unlink()
    if (size, digest) != (file.size, file.sha256):
        return f"{file.path}: differs ({size} bytes, SHA-256 {digest[:12]}...; pinned {file.size}, {file.sha256[:12]}...)"
    return None


def check(dataset: PinnedDataset, scratch: Path) -> list[str]:
    """What is wrong with ``dataset``'s origin (empty: nothing)."""
    if dataset.archive:  # the fetcher checks every member it takes against the manifest
        try:
            fetch_dataset(dataset, scratch, progress=False)
        except UnreachableError:
            raise
        except DataError as exc:
            return [str(exc)]
        return []
    folder = scratch / dataset.folder
    with ThreadPoolExecutor(max_workers=PARALLEL) as pool:
        problems = list(pool.map(lambda f: _check_file(dataset, f, folder), dataset.files))
    return [p for p in problems if p is not None]


def main(argv: list[str]) -> int:
    datasets = load_manifest()
    unknown = sorted(set(argv) - {d.name for d in datasets})
    if unknown:
        print(f"check_data_origins: no pinned dataset named {', '.join(unknown)}", file=sys.stderr)
        return 2
    chosen = [d for d in datasets if not argv or d.name in argv]
    failed = 0
    with tempfile.TemporaryDirectory(prefix="slamfront-origins-") as scratch:
        for dataset in chosen:
            try:
                problems = check(dataset, Path(scratch))
            except UnreachableError as exc:
                host = urlparse(dataset.origin).netloc
                print(f"check_data_origins: cannot reach {host} (no network?): nothing checked; "
                      f"{str(exc).split(': ', 2)[-1].split('. Offline?')[0]}", file=sys.stderr)
                return 2
            failed += bool(problems)
            pinned = dataset.origin
            if not problems:
                print(f"{dataset.name}: ok, {len(dataset.files)} files at {pinned}")
                continue
            print(f"{dataset.name}: {len(problems)} of {len(dataset.files)} files wrong at {pinned}")
            for problem in problems:
                print(f"  {problem}")
    print(f"{len(chosen) - failed} of {len(chosen)} origins hold their pinned files")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
