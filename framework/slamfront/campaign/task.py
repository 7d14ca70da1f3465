"""The one function that executes a campaign run, in a pool process or as a Ray task.

:func:`run_one` takes a picklable :class:`RunTask` and never raises for a failed run:
the error comes back in the :class:`RunOutcome`, so one bad run never stops a campaign.
Data paths in the recipe are resolved here, on the machine that runs it.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import platform
import tempfile
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from slamfront.errors import SlamfrontError, run_failure_of
from slamfront.outputs import write_atomically
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.registry import ENTRY_POINT_GROUP
from slamfront.runtime import run_pipeline

ERROR_FILE = "error.txt"
THREAD_VARIABLES = (
    "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
)


@dataclass(frozen=True)
class RunTask:
    """What a worker needs to execute one run."""

    key: str
    name: str
    recipe: dict[str, Any]
    """The resolved recipe as plain data; its data paths are still relative."""
    origin: str
    """The base recipe file (for messages and the log's provenance)."""
    out_dir: str | None
    """Write the run here (a folder the worker sees); None: a temporary folder whose files are returned."""
    max_frames: int | None = None
    threads: int = 1
    """Threads the run's libraries may use (OpenMP, BLAS, OpenCV)."""
    data_root: str | None = None
    """The data root on the worker (default: the worker's ``$SLAMFRONT_DATA`` or checkout)."""


@dataclass
class RunOutcome:
    """How a run ended, sent back to the campaign."""

    key: str
    status: Literal["ok", "failed"]
    error: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    wall_seconds: float = 0.0
    """The whole task: building the pipeline, running it, evaluating, reporting."""
    host: str = ""
    code: str = ""
    """:func:`code_fingerprint` of the worker that ran it."""
    files: dict[str, bytes] | None = None
    """The run folder's files by relative path, when the task had no ``out_dir``."""


def thread_environment(threads: int) -> dict[str, str]:
    """Thread-count variables for a worker, leaving any the user set alone."""
    return {name: str(threads) for name in THREAD_VARIABLES if name not in os.environ}


def limit_threads(threads: int) -> None:
    """Keep one run's libraries to ``threads`` threads, so parallel runs do not oversubscribe.

    The environment reaches libraries loaded after this call; OpenCV's pool is set directly.
    """
    os.environ.update(thread_environment(threads))
    import cv2

    cv2.setNumThreads(threads)


@functools.cache
def code_fingerprint() -> str:
    """What code a run executes, as a short sha256: the sources of slamfront and of every package
    the ``slamfront`` entry-point group names (the built-in plugins among them), with those
    distributions' names and versions. A campaign resumes a finished run only when this matches
    (a changed detector would otherwise mix two versions' results in one table). Plugin modules a
    recipe loads from a local path are not covered; ``--force`` reruns everything."""
    digest = hashlib.sha256()
    packages = {"slamfront"}
    owners = set()
    for entry_point in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        packages.add(entry_point.value.split(":")[0].split(".")[0])
        if entry_point.dist is not None:
            owners.add(f"{entry_point.dist.name} {entry_point.dist.version}")
    for package in sorted(packages):
        spec = importlib.util.find_spec(package)  # a top-level name: found, not imported
        for root in (spec.submodule_search_locations or []) if spec is not None else []:
            for path in sorted(Path(root).rglob("*.py")):
                digest.update(f"{package}/{path.relative_to(root)}".encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update("\n".join(sorted(owners)).encode())
    return digest.hexdigest()[:16]


def run_one(task: RunTask) -> RunOutcome:
    """Execute one run: ``parse_recipe`` -> ``build_pipeline`` -> ``run_pipeline``."""
    limit_threads(task.threads)
    started = time.perf_counter()
    with _run_folder(task.out_dir) as out_dir:
        outcome = RunOutcome(key=task.key, status="failed", host=platform.node(), code=code_fingerprint())
        try:
            recipe = parse_recipe(task.recipe, task.origin)
            data = Path(task.data_root) if task.data_root else None
            pipeline = build_pipeline(recipe, task.origin, data=data)
            result = run_pipeline(pipeline, task.origin, out_dir, progress=False, max_frames=task.max_frames)
            outcome.status, outcome.metrics = "ok", result.metrics
        except SlamfrontError as exc:
            outcome.error = f"{type(exc).__name__}: {exc}"
            write_atomically(out_dir / ERROR_FILE, outcome.error + "\n")
        except Exception as exc:  # a plugin's bug must not stop the campaign: record it with its traceback
            failure = run_failure_of(exc)
            outcome.error = f"{type(exc).__name__}: {exc}" + (f" ({failure.where})" if failure else "")
            write_atomically(out_dir / ERROR_FILE, traceback.format_exc())
        except (SystemExit, KeyboardInterrupt) as exc:
            # a run that calls sys.exit() or is interrupted ends that run, not the campaign
            # (on Ray the same run is a failed task too)
            outcome.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
            write_atomically(out_dir / ERROR_FILE, traceback.format_exc())
        outcome.wall_seconds = time.perf_counter() - started
        if task.out_dir is None:
            outcome.files = {
                str(path.relative_to(out_dir)): path.read_bytes() for path in sorted(out_dir.rglob("*")) if path.is_file()
            }
    return outcome


@contextlib.contextmanager
def _run_folder(out_dir: str | None) -> Iterator[Path]:
    if out_dir is not None:
        path = Path(out_dir)
        path.mkdir(parents=True, exist_ok=True)
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="slamfront-run-") as tmp:
        yield Path(tmp)
