"""Pinned datasets: the real data the tests read, fetchable and verifiable anywhere.

The manifest (``slamfront/resources/data_manifest.json``, written by
``scripts/make_data_manifest.py``) lists datasets. Each has a folder under the data
root, a public origin pinned to a commit or a release, a licence and citation, and
every file with its size and SHA-256. An origin is a base URL (file ``f`` is at
``<origin><f>``) or a zip archive (``f`` is one of its members); ``renames`` maps a file
to its name at the origin where the two differ.

:func:`fetch_dataset` brings the missing or damaged files of a dataset into a data
root: each download goes to ``<file>.part`` (an interrupted one resumes with an HTTP
range request), is checked against its SHA-256, and only then takes the file's name; a
file that fails the check is refused and removed. A mirror serves a copy of a data root:
file ``f`` of the dataset in folder ``d`` is ``<mirror>/d/f``, so any data root served
over HTTP (or a ``file://`` path to one) is a mirror.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, urlparse

from slamfront.data import MIRROR_ENV  # noqa: F401  (re-exported: the manifest's mirror variable)
from slamfront.datasets import download, sha256_of
from slamfront.errors import DataError

MANIFEST = Path(__file__).resolve().parent / "resources" / "data_manifest.json"
"""The shipped manifest."""


PARALLEL = 8
"""Files downloaded at once: many small files from one host are latency-bound."""


@dataclass(frozen=True)
class PinnedFile:
    """One file: its path in the dataset folder, size in bytes and SHA-256."""

    path: str
    size: int
    sha256: str


@dataclass(frozen=True)
class PinnedDataset:
    """A dataset of the manifest (see the module docstring)."""

    name: str
    folder: str
    title: str
    origin: str
    archive: bool
    licence: str
    citation: str
    files: tuple[PinnedFile, ...]
    renames: tuple[tuple[str, str], ...] = ()

    @property
    def size(self) -> int:
        return sum(f.size for f in self.files)

    def origin_name(self, file: PinnedFile) -> str:
        return dict(self.renames).get(file.path, file.path)

    def url(self, file: PinnedFile, mirror: str | None = None) -> str:
        """Where ``file`` is downloaded from: the mirror, else the origin (not for archives)."""
        if mirror is not None:
            return f"{mirror.rstrip('/')}/{quote(self.folder)}/{quote(file.path)}"
        return self.origin + quote(self.origin_name(file))

    def damaged(self, root: Path) -> list[PinnedFile]:
        """The files absent from ``root/<folder>`` or differing from the manifest there."""
        folder = root / self.folder
        return [f for f in self.files if not _matches(folder / f.path, f)]


def load_manifest(path: Path | None = None) -> list[PinnedDataset]:
    """The datasets of a manifest file (default: the shipped one)."""
    raw = json.loads((path or MANIFEST).read_text())
    return [
        PinnedDataset(
            name=d["name"], folder=d["folder"], title=d["title"], origin=d["origin"], archive=bool(d["archive"]),
            licence=d["licence"], citation=d["citation"], renames=tuple(sorted(d.get("renames", {}).items())),
            files=tuple(PinnedFile(path, int(size), digest) for path, size, digest in d["files"]),
        )
        for d in raw["datasets"]
    ]


def dataset_summaries(path: Path | None = None) -> list[tuple[str, str, int, int, str]]:
    """(name, folder, files, bytes, licence) of each dataset of a manifest, without building
    its file records (``slamfront datasets`` lists 7,000 files' worth in a few ms)."""
    raw = json.loads((path or MANIFEST).read_text())
    return [(d["name"], d["folder"], len(d["files"]), sum(f[1] for f in d["files"]), d["licence"])
            for d in raw["datasets"]]


def _matches(path: Path, file: PinnedFile) -> bool:
    return path.is_file() and path.stat().st_size == file.size and sha256_of(path) == file.sha256


def _install(candidate: Path, target: Path, file: PinnedFile, source: str) -> None:
    """Move a downloaded ``candidate`` to ``target`` if its checksum is the manifest's, else refuse it."""
    digest = sha256_of(candidate)
    if digest != file.sha256:
        candidate.unlink()
        raise DataError(
            f"{target}: SHA-256 {digest} of the file from {source} is not the pinned {file.sha256}; refused "
            "(a damaged download, or the origin changed)"
        )
    os.replace(candidate, target)


def fetch_dataset(
    dataset: PinnedDataset,
    root: Path,
    mirror: str | None = None,
    progress: bool | None = None,
    timeout: float = 30.0,
) -> int:
    """Download the missing or damaged files of ``dataset`` into ``root/<folder>``; returns their count.

    :param mirror: a mirror base URL (see the module docstring) instead of the origin.
    :raises DataError: a file cannot be downloaded or fails its checksum (files already
        fetched stay; the next call fetches only the rest).
    """
    todo = dataset.damaged(root)
    if not todo:
        return 0
    from tqdm import tqdm  # not at import: listing the manifest needs no progress bar

    folder = root / dataset.folder
    with tqdm(total=sum(f.size for f in todo), unit="B", unit_scale=True, desc=dataset.name,
              disable=None if progress is None else not progress) as bar:
        if dataset.archive and mirror is None:
            _fetch_from_archive(dataset, todo, root, folder, timeout, bar.update)
        else:
            _fetch_files(dataset, todo, folder, mirror, timeout, bar.update)
    return len(todo)


def _fetch_files(
    dataset: PinnedDataset, todo: list[PinnedFile], folder: Path, mirror: str | None, timeout: float,
    advance: Callable[[int], None],
) -> None:
    from concurrent.futures import ThreadPoolExecutor  # not at import: listing the manifest needs none

    def one(file: PinnedFile) -> None:
        target = folder / file.path
        target.parent.mkdir(parents=True, exist_ok=True)
        candidate = target.with_name(target.name + ".download")
        url = dataset.url(file, mirror)
        download(url, candidate, dataset.name, timeout, retry=f"slamfront datasets fetch {dataset.name}")
        _install(candidate, target, file, url)
        advance(file.size)

    with ThreadPoolExecutor(max_workers=PARALLEL) as pool:
        futures = [pool.submit(one, file) for file in todo]
        try:
            for future in futures:
                future.result()
        except BaseException:
            # the first failure stops the rest (offline, each would fail in turn); the
            # files already fetched stay, and the next call fetches only the others
            for future in futures:
                future.cancel()
            raise


def _fetch_from_archive(
    dataset: PinnedDataset, todo: list[PinnedFile], root: Path, folder: Path, timeout: float,
    advance: Callable[[int], None],
) -> None:
    """Download the dataset's archive (resumable) beside its folder, take the files from it, delete it."""
    import tempfile
    import zipfile

    archive = root / f".{dataset.name}{Path(urlparse(dataset.origin).path).suffix}"
    archive.parent.mkdir(parents=True, exist_ok=True)
    if not archive.exists():
        download(dataset.origin, archive, dataset.name, timeout, retry=f"slamfront datasets fetch {dataset.name}")
    try:
        with zipfile.ZipFile(archive) as bundle:
            members = {Path(n).as_posix(): n for n in bundle.namelist()}
            for file in todo:
                wanted = dataset.origin_name(file)
                # archives often wrap their files in one top folder
                key = wanted if wanted in members else next((m for m in members if m.endswith("/" + wanted)), None)
                if key is None:
                    raise DataError(f"{dataset.origin}: the archive has no {wanted}")
                target = folder / file.path
                target.parent.mkdir(parents=True, exist_ok=True)
                with bundle.open(members[key]) as src, tempfile.NamedTemporaryFile(
                    dir=target.parent, prefix=f".{target.name}.", delete=False
                ) as dst:
                    while chunk := src.read(1 << 20):
                        dst.write(chunk)
                _install(Path(dst.name), target, file, dataset.origin)
                advance(file.size)
    except zipfile.BadZipFile as exc:
        archive.unlink()
        raise DataError(f"{dataset.origin}: not a valid zip archive ({exc}); removed, fetch again") from exc
    archive.unlink()
