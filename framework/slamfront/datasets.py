"""Downloading public datasets into the download folder: official URL, checksum, resumable, extracted.

A source plugin lists the datasets it reads in its ``downloads`` class attribute
(:class:`DatasetDownload` records); ``slamfront datasets`` shows them and fetches one
into ``download_root()/<name>/``. A download is written to ``<name>.<ext>.part`` and
resumed with an HTTP range request when interrupted; the finished archive is checked
against its published SHA-256 (or, when the publisher gives none, its checksum is
recorded beside it and printed so it can be compared and pinned), then extracted
safely (no member may escape the target folder). Offline, the error says where to put
an archive fetched by other means: the next ``download`` only verifies and extracts it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from slamfront.data import download_root
from slamfront.errors import DataError

COMPLETE_MARKER = ".slamfront-complete"
"""Written into a dataset folder once it is fully extracted (holds the URL and checksum)."""

_CHUNK = 1 << 20


class UnreachableError(DataError):
    """The host could not be reached at all (offline, DNS, refused), as opposed to an HTTP error."""


@dataclass(frozen=True)
class DatasetDownload:
    """Where a public dataset comes from and how it unpacks.

    :ivar name: folder name (under the download folder) and the name ``slamfront datasets download`` takes.
    :ivar url: the official direct-download URL; None when there is none (``manual``
        then says how to get the data).
    :ivar sha256: the archive's published SHA-256, or None when the publisher gives none.
    :ivar archive: ``zip``, ``tar`` (any compression) or ``file`` (kept as is).
    :ivar members: extract only archive members under this prefix ("" = all).
    :ivar strip: leading path removed from extracted member names.
    :ivar expect: paths (relative to the dataset folder) that must exist afterwards.
    :ivar manual: how to get the data by hand; ``{cache}`` is replaced by the download folder.
    """

    name: str
    title: str
    url: str | None
    homepage: str
    license: str
    archive: Literal["zip", "tar", "file"] = "zip"
    sha256: str | None = None
    members: str = ""
    strip: str = ""
    expect: tuple[str, ...] = ()
    manual: str = ""

    def folder(self, cache: Path | None = None) -> Path:
        """Where the extracted dataset lives."""
        return (cache or download_root()) / self.name

    def archive_path(self, cache: Path | None = None) -> Path:
        suffix = {"zip": ".zip", "tar": ".tar", "file": ""}[self.archive]
        return (cache or download_root()) / f"{self.name}{suffix}"

    def is_installed(self, cache: Path | None = None) -> bool:
        return (self.folder(cache) / COMPLETE_MARKER).is_file()


def fetch(
    spec: DatasetDownload,
    cache: Path | None = None,
    url: str | None = None,
    progress: bool | None = None,
    timeout: float = 30.0,
    report: Callable[[str], None] = print,
) -> Path:
    """Make ``spec`` available in the download folder ``cache`` and return its folder.

    :param url: use this URL instead of the official one (a mirror, a ``file://`` copy).
    :param progress: show a byte progress bar (None: only on a terminal).
    :param report: where notes go (the recorded checksum when none is published).
    :raises DataError: no URL, network failure, checksum mismatch, corrupt archive.
    """
    cache = cache or download_root()
    folder = spec.folder(cache)
    if spec.is_installed(cache):
        return folder
    source = url or spec.url
    archive = spec.archive_path(cache)
    if source is None and not archive.exists():
        raise DataError(f"{spec.name}: no direct download. {spec.manual.format(cache=cache)}".strip())
    cache.mkdir(parents=True, exist_ok=True)
    if not archive.exists():
        download(source, archive, spec.name, timeout, progress=progress)  # type: ignore[arg-type]
    digest = sha256_of(archive)
    if spec.sha256 is not None and digest != spec.sha256.lower():
        bad = archive.with_name(archive.name + ".bad")
        os.replace(archive, bad)
        raise DataError(
            f"{archive}: SHA-256 {digest} does not match the published {spec.sha256}; "
            f"moved to {bad.name} (a truncated or altered download). Run the download again."
        )
    if spec.sha256 is None:
        recorded = archive.with_name(archive.name + ".sha256")
        if recorded.exists() and recorded.read_text().split()[0] != digest:
            raise DataError(f"{archive}: SHA-256 {digest} differs from the one recorded in {recorded.name}")
        recorded.write_text(f"{digest}  {archive.name}\n")
        report(f"{spec.name}: no published checksum; recorded SHA-256 {digest} in {recorded}")
    _extract(spec, archive, folder)
    missing = [p for p in spec.expect if not (folder / p).exists()]
    if missing:
        raise DataError(f"{folder}: the archive did not contain {', '.join(missing)}")
    (folder / COMPLETE_MARKER).write_text(json.dumps({"url": source, "sha256": digest}) + "\n")
    return folder


def download(
    url: str, target: Path, name: str, timeout: float = 30.0, retry: str | None = None, progress: bool | None = False
) -> None:
    """Fetch ``url`` to ``target`` through ``target.part``, resuming a partial file.

    :param retry: the command that resumes the download, for messages
        (default ``slamfront datasets download NAME``).
    :raises UnreachableError: the host cannot be reached (kept bytes resume next time).
    :raises DataError: an HTTP error, or the transfer ended early.
    """
    retry = retry or f"slamfront datasets download {name}"
    part = target.with_name(target.name + ".part")
    have = part.stat().st_size if part.exists() else 0
    # not at import: `slamfront datasets` lists the records of this module without them
    import urllib.error
    import urllib.request

    from tqdm import tqdm

    request = urllib.request.Request(url, headers={"User-Agent": "slamfront"})
    if have:
        request.add_header("Range", f"bytes={have}-")
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            status = getattr(response, "status", None) or response.getcode() or 200
            resumed = have > 0 and status == 206
            length = response.headers.get("Content-Length")
            total = (int(length) + (have if resumed else 0)) if length else None
            with open(part, "ab" if resumed else "wb") as out, tqdm(
                total=total, initial=have if resumed else 0, unit="B", unit_scale=True, desc=name,
                disable=None if progress is None else not progress,
            ) as bar:
                while chunk := response.read(_CHUNK):
                    out.write(chunk)
                    bar.update(len(chunk))
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # asked past the end: the part file is already whole
            os.replace(part, target)
            return
        raise DataError(f"cannot download {name} from {url}: HTTP {exc.code} {exc.reason}") from exc
    except (urllib.error.URLError, OSError, TimeoutError) as exc:
        reason = getattr(exc, "reason", None) or exc
        kept = f" ({part.stat().st_size} bytes kept in {part}; the next try resumes)" if part.exists() else ""
        raise UnreachableError(
            f"cannot download {name} from {url}: {reason}{kept}. Offline? Fetch the file by other "
            f"means, save it as {target} and run `{retry}` again."
        ) from exc
    if total is not None and part.stat().st_size < total:
        raise DataError(
            f"download of {name} from {url} ended early ({part.stat().st_size} of {total} bytes, kept in "
            f"{part}); run `{retry}` again to resume"
        )
    os.replace(part, target)


def sha256_of(path: Path) -> str:
    import hashlib  # the imports of this module are kept to what listing its records needs

    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _member_target(name: str, spec: DatasetDownload, root: Path) -> Path | None:
    """Where an archive member goes, or None to skip it. Refuses paths leaving ``root``."""
    if spec.members and not name.startswith(spec.members):
        return None
    relative = name[len(spec.strip) :] if spec.strip and name.startswith(spec.strip) else name
    relative = relative.lstrip("/")
    if not relative:
        return None
    target = (root / relative).resolve()
    if root.resolve() not in target.parents and target != root.resolve():
        raise DataError(f"archive member {name!r} would be written outside {root}: refused")
    return target


def _extract(spec: DatasetDownload, archive: Path, folder: Path) -> None:
    """Extract into a temporary folder beside ``folder``, then move it into place."""
    import shutil
    import tarfile
    import tempfile
    import zipfile

    staging = Path(tempfile.mkdtemp(prefix=f".{spec.name}-", dir=folder.parent))
    try:
        if spec.archive == "file":
            shutil.copy2(archive, staging / archive.name)
        elif spec.archive == "zip":
            try:
                with zipfile.ZipFile(archive) as bundle:
                    for info in bundle.infolist():
                        target = _member_target(info.filename, spec, staging)
                        if target is None or info.is_dir():
                            continue
                        target.parent.mkdir(parents=True, exist_ok=True)
                        with bundle.open(info) as src, open(target, "wb") as dst:
                            shutil.copyfileobj(src, dst)
            except zipfile.BadZipFile as exc:
                raise DataError(f"{archive}: not a valid zip archive ({exc}); delete it and download again") from exc
        else:
            try:
                with tarfile.open(archive) as bundle:
                    for member in bundle:
                        target = _member_target(member.name, spec, staging)
                        if target is None or not member.isfile():
                            continue
                        target.parent.mkdir(parents=True, exist_ok=True)
                        with bundle.extractfile(member) as src, open(target, "wb") as dst:  # type: ignore[union-attr]
                            shutil.copyfileobj(src, dst)
            except tarfile.TarError as exc:
                raise DataError(f"{archive}: not a valid tar archive ({exc}); delete it and download again") from exc
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(staging, folder)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
