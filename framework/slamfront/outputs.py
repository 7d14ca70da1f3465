"""A run's output folder holds one run's files, never a mix of two, and nothing else is touched.

A run holds the folder's lock (``DIR/.slamfront-lock``) while it writes there: a second
``run``, ``replay`` or ``sweep`` into the same folder stops at once with one line naming
the holder's process (the system releases the lock when a process dies, so a killed
run's lock is simply taken over).

A run records every file it writes in ``DIR/.slamfront-run`` (a small JSON manifest, with
each file's size and SHA-256), when it starts, after each fsync of its log (the log's
size and the hash of what had been synced), and when it ends, however it ends. Running
again into the same folder first removes the files the manifest vouches for, that is
files still exactly as the previous run wrote them, and says so; anything else in the
folder is left alone. A file the run would replace and that no manifest vouches for
(``run.mcap``, ``metrics.json``, ``report.md`` or ``report.html`` edited by hand, put
there, or left by an older slamfront) stops the run with one line before anything is
written. "The run's files" are the files that appeared in the folder (or were replaced
there) while the run held it: a writer registers nothing, so every output a plugin or an
evaluation writes into ``out_dir`` is recorded the same way.

No output is ever written through a link: a folder holding a symbolic link to a file (or
a dangling one) is refused, with one line naming the link, and outputs are created with
``O_NOFOLLOW`` (:func:`open_output`) or written beside their name and renamed onto it
(:func:`write_atomically`), which replaces a link planted later instead of following it.

Inputs are protected by file identity (device and inode), not by path: a replay or a
recovery never writes over, or removes, the log it reads, whether the two paths are
the same file by name, through a hard link, a symbolic link or a bind mount.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import stat
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from slamfront.errors import SlamfrontError

MANIFEST = ".slamfront-run"
LOCK_FILE = ".slamfront-lock"
OWN_OUTPUTS = ("run.mcap", "metrics.json", "report.md", "report.html")
"""Files every run writes: one of these that no manifest vouches for stops the run before it starts."""
_FORMAT = 2
_TEMPORARY = re.compile(r"^\..+\.tmp-\d+$")
"""Names :func:`write_atomically` writes to before renaming (a killed writer may leave one)."""
_BLOCK = 1 << 20


def file_identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of the file ``path`` names (links followed), None when there is none."""
    try:
        info = os.stat(path)
    except OSError:
        return None
    return info.st_dev, info.st_ino


def same_file(a: Path, b: Path) -> bool:
    """``a`` and ``b`` are one file on disk (hard link, symbolic link, bind mount or same path)."""
    first = file_identity(a)
    return first is not None and first == file_identity(b)


def refuse_overwrite(target: Path, inputs: Iterable[Path], what: str) -> None:
    """Raise when writing ``target`` would overwrite one of ``inputs``.

    :raises SlamfrontError: naming the input and ``what`` should change.
    """
    for source in inputs:
        if same_file(target, source):
            raise SlamfrontError(f"{target}: is the input {source} (the same file on disk); {what}")


def make_folder(path: Path, what: str = "output folder") -> Path:
    """``mkdir -p``, with a failure said in one line."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SlamfrontError(f"{path}: cannot create the {what}: {exc.strerror or exc}") from None
    if not path.is_dir():
        raise SlamfrontError(f"{path}: cannot create the {what}: a file of that name exists")
    return path


# -- writing without following links ----------------------------------------------------------


def _link_error(path: Path) -> SlamfrontError:
    try:
        target = f" (to {os.readlink(path)})"
    except OSError:
        target = ""
    return SlamfrontError(
        f"{path}: is a symbolic link{target}; slamfront never writes through a link in an output folder "
        "(it could point anywhere): remove it or choose another output folder"
    )


def open_output(path: Path) -> IO[bytes]:
    """``path`` opened for writing from its start, never through a link: a symbolic
    link, a hard-linked file (whose other names would change too) or anything but a
    regular file there is refused.

    :raises SlamfrontError: ``path`` is a link or not a regular file.
    :raises OSError: it cannot be created (a missing folder, no permission, a full disk).
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        if os.path.islink(path):
            raise _link_error(path) from None
        raise exc from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise SlamfrontError(f"{path}: is not a regular file; remove it or choose another output path")
        if info.st_nlink > 1:
            raise SlamfrontError(
                f"{path}: is a hard link of another file ({info.st_nlink} names), which writing it would change too; "
                "remove it or choose another output path"
            )
        os.set_blocking(fd, True)
        os.ftruncate(fd, 0)
        return os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        raise


def write_atomically(
    path: Path, data: bytes | str, announce: Callable[[Path, int, str], None] | None = None
) -> Path:
    """Write ``data`` beside ``path`` and rename it onto ``path``: a reader never sees half
    a file, and a link at ``path`` is replaced, never followed.

    :param announce: called with ``(path, size, sha256)`` once the data is on disk and before
        the rename (:meth:`RunFolder.announce`), so a run killed at any moment has already
        vouched for the file it leaves.
    :raises OSError: the folder cannot be written (a full disk, no permission).
    """
    path = Path(path)
    content = data.encode() if isinstance(data, str) else data
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.unlink(missing_ok=True)  # a killed writer's leftover (unlink never follows a link)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    try:
        with os.fdopen(fd, "wb") as stream:
            stream.write(content)
        if announce is not None:
            import hashlib  # only runs announce files: `slamfront optimize` does without (~3 ms of OpenSSL)

            announce(path, len(content), hashlib.sha256(content).hexdigest())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


# -- one writer per folder --------------------------------------------------------------------


class FolderLock:
    """An exclusive ``flock`` on ``DIR/.slamfront-lock``, released by :meth:`release` or by
    the system when the process ends: a lock left by a dead process is taken over."""

    def __init__(self, folder: Path, what: str) -> None:
        self.folder = folder
        path = folder / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            if os.path.islink(path):
                raise _link_error(path) from None
            raise SlamfrontError(f"{path}: cannot create the folder's lock: {exc.strerror or exc}") from None
        self._handle: IO[str] | None = os.fdopen(fd, "r+")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = self._holder()
            self.release()
            raise SlamfrontError(
                f"{folder}: {holder} is using this folder; wait for it to end or choose another output folder"
            ) from None
        self._handle.truncate()
        self._handle.write(f"{what} process {os.getpid()}\n")
        self._handle.flush()

    def _holder(self) -> str:
        assert self._handle is not None
        for _ in range(20):  # the holder writes its name just after it took the lock
            self._handle.seek(0)
            text = self._handle.read(200).strip()
            what, _, pid = text.rpartition(" process ")
            if pid.isdigit():
                return f"another {what or 'slamfront command'} (process {pid})"
            time.sleep(0.01)
        return "another process"

    @property
    def held(self) -> bool:
        return self._handle is not None

    def release(self) -> None:
        """Let the next run in. Safe to call twice."""
        if self._handle is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._handle.fileno(), fcntl.LOCK_UN)
            self._handle.close()
            self._handle = None


@contextlib.contextmanager
def folder_lock(folder: Path, what: str) -> Iterator[FolderLock]:
    """Hold ``folder``'s lock (created if missing) for the ``with`` block: one run, replay
    or campaign at a time per folder.

    :param what: what holds it (``run``, ``campaign``), named to whoever is refused.
    :raises SlamfrontError: another process holds it (naming that process).
    """
    lock = FolderLock(make_folder(folder), what)
    try:
        yield lock
    finally:
        lock.release()


# -- what a run wrote -----------------------------------------------------------------------


def _digest(path: Path, size: int | None = None) -> str | None:
    """SHA-256 of ``path`` (of its first ``size`` bytes), never through a link; None if unreadable."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    import hashlib

    with os.fdopen(fd, "rb") as stream:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        digest, left = hashlib.sha256(), size if size is not None else -1
        while left != 0:
            block = stream.read(_BLOCK if left < 0 else min(_BLOCK, left))
            if not block:
                return None if left > 0 else digest.hexdigest()
            digest.update(block)
            left -= len(block) if left > 0 else 0
        return digest.hexdigest()


def _files(folder: Path) -> dict[str, os.stat_result]:
    """Regular files in ``folder`` (links not followed), without the folder's own bookkeeping."""
    found: dict[str, os.stat_result] = {}
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return found
    for entry in entries:
        if entry.name in (MANIFEST, LOCK_FILE) or _TEMPORARY.match(entry.name):
            continue
        with contextlib.suppress(OSError):
            info = entry.stat(follow_symlinks=False)
            if stat.S_ISREG(info.st_mode):
                found[entry.name] = info
    return found


def _identity(info: os.stat_result) -> tuple[int, int, int, int]:
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns


def refuse_links(folder: Path) -> None:
    """A symbolic link in the folder that a write could follow (to a file, or dangling) stops the run."""
    with contextlib.suppress(OSError):
        for entry in sorted(os.scandir(folder), key=lambda e: e.name):
            if entry.is_symlink() and not entry.is_dir(follow_symlinks=True):
                raise _link_error(Path(folder) / entry.name)


def _read_manifest(folder: Path) -> dict[str, Any]:
    try:
        data = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) and data.get("format") == _FORMAT else {}


def _vouched(folder: Path, manifest: dict[str, Any], present: dict[str, os.stat_result]) -> set[str]:
    """The files ``manifest`` vouches for: the previous run's, still exactly as it wrote them
    (size and SHA-256; for an unfinished run's log, what it had synced and its inode)."""
    files = manifest.get("files")
    if not isinstance(files, dict):
        return set()
    vouched = set()
    for name, entry in files.items():
        info = present.get(name) if isinstance(name, str) else None
        if info is None or not isinstance(entry, dict):
            continue
        size, digest = entry.get("size"), entry.get("sha256")
        if not isinstance(size, int) or isinstance(size, bool) or not isinstance(digest, str) or len(digest) != 64:
            continue
        if entry.get("prefix") is True:
            # a log whose writer never finished: vouched for by what it had fsynced, on the same inode
            partial = name == "run.mcap" and size >= 0
            if not partial or [entry.get("dev"), entry.get("ino")] != [info.st_dev, info.st_ino]:
                continue
            if info.st_size >= size and _digest(folder / name, size) == digest and (size > 0 or _starts_a_log(folder / name)):
                vouched.add(name)
        elif info.st_size == size and _digest(folder / name) == digest:
            vouched.add(name)
    return vouched


def _starts_a_log(path: Path) -> bool:
    """``path`` is empty or begins like an MCAP file: a log created but never synced (its
    inode alone could have been reused by a file of the user's since)."""
    from slamfront.mcaplog.scan import MAGIC  # the log package writes through this module

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return False
    with os.fdopen(fd, "rb") as stream:
        head = stream.read(len(MAGIC))
    return MAGIC.startswith(head)


@dataclass
class RunFolder:
    """A run's output folder, claimed (and locked) by :func:`claim_run_folder`.

    Close it (or use it as a context manager) when the run has written its last file.
    """

    path: Path
    lock: FolderLock
    before: dict[str, tuple[int, int]]
    """Files in the folder that are not this run's, by (device, inode): a file the run
    replaces (written beside its name and renamed onto it) is a new inode, the run's."""
    replaced: list[str] = field(default_factory=list)
    """Files of a previous run that were removed."""
    _log: dict[str, Any] | None = None
    _log_finished: bool = False
    """The log's writer closed the file: ``_log`` is all of it (else a prefix; a stopped
    writer's buffer may still reach the disk as the process exits)."""
    _digests: dict[tuple[int, int, int, int], str] = field(default_factory=dict)
    _announced: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Files about to be renamed into place (:meth:`announce`), by name: size and SHA-256."""

    def written(self) -> dict[str, os.stat_result]:
        """The files this run has written so far."""
        return {
            name: info for name, info in _files(self.path).items() if self.before.get(name) != (info.st_dev, info.st_ino)
        }

    def log_synced(self, size: int, sha256: str, finished: bool = False) -> None:
        """The log ``run.mcap`` has its first ``size`` bytes on disk, hashing to ``sha256``:
        a rerun after a kill may then remove it (its writer calls this on creation, after each
        fsync and, with ``finished``, after closing the file)."""
        with contextlib.suppress(OSError):
            info = os.stat(self.path / "run.mcap", follow_symlinks=False)
            self._log = {"size": size, "sha256": sha256, "prefix": True, "dev": info.st_dev, "ino": info.st_ino}
            self._log_finished = finished
            self.record(complete=False)

    def announce(self, path: Path, size: int, sha256: str) -> None:
        """``path`` (in this folder) is about to be renamed into place with this content:
        record it now, so a kill between the rename and the next record leaves no file that
        no manifest vouches for (pass it as ``announce`` to :func:`write_atomically`)."""
        self._announced[Path(path).name] = {"size": size, "sha256": sha256}
        self.record(complete=False)

    def record(self, complete: bool) -> None:
        """Write the manifest: every file this run wrote so far, with its size and SHA-256,
        and the files it announced and may not have renamed into place yet."""
        files: dict[str, dict[str, Any]] = dict(self._announced)
        for name, info in self.written().items():
            log = self._log if name == "run.mcap" and self._log is not None else None
            if complete and log is not None and self._log_finished and [log["dev"], log["ino"], log["size"]] == [
                info.st_dev, info.st_ino, info.st_size
            ]:
                files[name] = {"size": log["size"], "sha256": log["sha256"]}  # the whole log, as its writer hashed it
                continue
            if log is not None or (name == "run.mcap" and not complete):
                # the log is being written, or its writer was stopped before it could finish
                # (its buffer may still reach the disk): what its last fsync put there
                if log is not None:
                    files[name] = log
                continue
            key = _identity(info)
            if key not in self._digests:
                digest = _digest(self.path / name)
                if digest is None:
                    continue
                self._digests[key] = digest
            files[name] = {"size": info.st_size, "sha256": self._digests[key]}
        data = {"format": _FORMAT, "complete": complete, "pid": os.getpid(), "files": files}
        with contextlib.suppress(OSError):  # the manifest only helps the next run tidy up; never fail a run for it
            write_atomically(self.path / MANIFEST, json.dumps(data) + "\n")

    def close(self) -> None:
        """Record the run as ended and release the folder. Safe to call twice."""
        if self.lock.held:
            try:
                self.record(complete=True)
            finally:
                self.lock.release()

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def claim_run_folder(path: Path, inputs: Iterable[Path] = ()) -> RunFolder:
    """Prepare ``path`` for a run's outputs: create and lock it, remove a previous run's
    files (with a note on stderr), and record the new run as started.

    :param inputs: files the run reads; removing or overwriting any of them is refused.
    :raises SlamfrontError: the folder cannot be created, another run holds it, it holds a
        symbolic link, an input the run would replace, or one of the run's usual outputs
        that no manifest vouches for.
    """
    lock = FolderLock(make_folder(path), "run")
    try:
        refuse_links(path)
        present = _files(path)
        previous = _vouched(path, _read_manifest(path), present)
        inputs = list(inputs)
        for name in sorted(previous | {"run.mcap"}):
            refuse_overwrite(path / name, inputs, "choose another output folder")
        for name in OWN_OUTPUTS:
            if name in present and name not in previous:
                raise SlamfrontError(
                    f"{path / name}: no record of a previous run in this folder vouches for this file (changed since "
                    "a run wrote it, put here by hand, left by an older slamfront or by a run killed before its log "
                    "reached the disk); a run would replace it: move it away or choose another output folder"
                )
        for name in sorted(previous):
            try:
                (path / name).unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:
                raise SlamfrontError(f"{path / name}: cannot remove the previous run's file: {exc.strerror or exc}") from None
        if previous:
            print(f"slamfront: note: {path} held a previous run; its {len(previous)} files were removed", file=sys.stderr)
        kept = {name: (info.st_dev, info.st_ino) for name, info in _files(path).items()}
        folder = RunFolder(path, lock, before=kept, replaced=sorted(previous))
        folder.record(complete=False)
    except BaseException:
        lock.release()
        raise
    return folder


def safe_name(name: str) -> str:
    """``name`` (a recipe's, perhaps from a foreign log) as one harmless folder name:
    letters, digits, ``-``, ``_``, ``.`` and ``=`` only, never ``..``, absolute or empty."""
    cleaned = re.sub(r"[^A-Za-z0-9_.=-]+", "_", name).strip("._") or "run"
    return cleaned[:100]
