"""A run's output folder holds one run's files, never a mix of two runs.

A run records the files it writes in ``DIR/.slamfront-run`` (a small JSON manifest,
written when the run starts and again when it ends, however it ends). Running again
into the same folder first removes exactly those files and says so; anything else in
the folder (the recipe, notes) is left alone. A folder written by an older slamfront
(no manifest) loses its ``run.mcap``, ``metrics.json`` and ``report.md``.

Inputs are protected by file identity (device and inode), not by path: a replay or a
recovery never writes over, or removes, the log it reads, whether the two paths are
the same file by name, through a hard link, a symbolic link or a bind mount.
"""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from slamfront.errors import SlamfrontError

MANIFEST = ".slamfront-run"
LEGACY_OUTPUTS = ("run.mcap", "metrics.json", "report.md")


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


def _names(folder: Path) -> set[str]:
    try:
        return {entry.name for entry in os.scandir(folder) if entry.is_file(follow_symlinks=False)}
    except OSError:
        return set()


def _read_manifest(folder: Path) -> dict[str, object] | None:
    try:
        data = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _plain_names(values: object) -> set[str]:
    """File names a manifest lists, keeping only bare names (never a path elsewhere)."""
    if not isinstance(values, list):
        return set()
    return {v for v in values if isinstance(v, str) and v and v == Path(v).name and v not in (".", "..")}


@dataclass
class RunFolder:
    """A run's output folder, claimed by :func:`claim_run_folder`."""

    path: Path
    before: set[str]
    """Files in the folder that are not this run's (after the previous run's were removed)."""
    replaced: list[str] = field(default_factory=list)
    """Files of a previous run that were removed."""

    def record(self, complete: bool) -> None:
        """Write the manifest: every file this run wrote so far."""
        files = sorted((_names(self.path) - self.before - {MANIFEST}) | {"run.mcap"})
        data = {"complete": complete, "files": files, "before": sorted(self.before)}
        try:
            tmp = self.path / (MANIFEST + ".tmp")
            tmp.write_text(json.dumps(data) + "\n")
            os.replace(tmp, self.path / MANIFEST)
        except OSError:
            pass  # the manifest only helps the next run tidy up; never fail a run for it


def claim_run_folder(path: Path, inputs: Iterable[Path] = ()) -> RunFolder:
    """Prepare ``path`` for a run's outputs: create it, remove a previous run's files
    (with a note on stderr), and record the new run as started.

    :param inputs: files the run reads; removing or overwriting any of them is refused.
    :raises SlamfrontError: the folder cannot be created, or holds an input the run would replace.
    """
    make_folder(path)
    present = _names(path)
    manifest = _read_manifest(path)
    if manifest is None:
        previous = present & set(LEGACY_OUTPUTS) if "run.mcap" in present else set()
    elif manifest.get("complete") is True:
        previous = _plain_names(manifest.get("files")) & present
    else:  # the previous run never ended (killed): everything that appeared while it ran
        previous = (_plain_names(manifest.get("files")) | (present - _plain_names(manifest.get("before")))) & present
    previous.discard(MANIFEST)
    inputs = list(inputs)
    for name in sorted(previous | {"run.mcap"}):
        refuse_overwrite(path / name, inputs, "choose another output folder")
    for name in sorted(previous):
        try:
            (path / name).unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise SlamfrontError(f"{path / name}: cannot remove the previous run's file: {exc.strerror or exc}") from None
    if previous:
        print(f"slamfront: note: {path} held a previous run; its {len(previous)} files were removed", file=sys.stderr)
    folder = RunFolder(path, before=_names(path) - {MANIFEST}, replaced=sorted(previous))
    folder.record(complete=False)
    return folder


def safe_name(name: str) -> str:
    """``name`` (a recipe's, perhaps from a foreign log) as one harmless folder name:
    letters, digits, ``-``, ``_``, ``.`` and ``=`` only, never ``..``, absolute or empty."""
    cleaned = re.sub(r"[^A-Za-z0-9_.=-]+", "_", name).strip("._") or "run"
    return cleaned[:100]
