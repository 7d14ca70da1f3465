"""A campaign's folder: one sub-folder per run, each with a record of how it ended.

```
DIR/sweep.yaml                the sweep file as run
DIR/runs/<name>/run.mcap      each run's own log, metrics.json, report.md, pr_curve.csv ...
DIR/runs/<name>/sweep_run.json  the run's key, factors, status, error and timing
DIR/results.csv, results.json, report.md, *.png
```

A run counts as finished when its record says ``ok`` and its ``metrics.json`` is there;
resuming skips it by key, wherever its folder is (factor labels may have been renamed).
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from slamfront.campaign.plan import PlannedRun
from slamfront.campaign.task import RunOutcome
from slamfront.errors import SlamfrontError
from slamfront.outputs import folder_lock, make_folder, refuse_links, write_atomically

RECORD_FILE = "sweep_run.json"
METRICS_FILE = "metrics.json"


class CampaignStore:
    """Reads and writes the run folders of one campaign output folder."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.runs_dir = root / "runs"

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the folder's lock for a campaign's lifetime (the same lock a run holds,
        :func:`slamfront.outputs.folder_lock`): a second campaign, or a run, started into the
        same folder would remove the first one's runs in progress.

        :raises SlamfrontError: another process holds the lock.
        """
        make_folder(self.root, "campaign folder")
        with folder_lock(self.root, "campaign"):
            refuse_links(self.root)  # sweep.yaml, results.csv, report.md... are written there
            make_folder(self.runs_dir, "campaign folder")  # only once the folder is ours
            yield

    def finished(self, code: str | None = None) -> dict[str, Path]:
        """``{key: run folder}`` of every run recorded as ``ok`` with its metrics present (made by
        the code ``code``, :func:`slamfront.campaign.task.code_fingerprint`, unless None)."""
        found: dict[str, Path] = {}
        for record_path in sorted(self.runs_dir.glob(f"*/{RECORD_FILE}")):
            record = self.read_record(record_path.parent)
            if record is not None and record.get("status") == "ok" and (record_path.parent / METRICS_FILE).is_file() \
                    and (code is None or record.get("code") == code):
                found[str(record.get("key"))] = record_path.parent
        return found

    def prepare(self, run: PlannedRun) -> Path:
        """An empty folder for ``run`` (what an interrupted attempt left there is removed)."""
        folder = self.runs_dir / run.name
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        return folder

    def save_files(self, folder: Path, files: dict[str, bytes]) -> None:
        """Files a remote worker sent back (``RunOutcome.files``)."""
        for relative, data in files.items():
            parts = Path(relative).parts
            if not parts or Path(relative).is_absolute() or ".." in parts:
                raise SlamfrontError(f"{folder}: a worker sent back a file outside its run folder: {relative!r}")
            path = folder / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(path, data)

    def record(self, run: PlannedRun, folder: Path, outcome: RunOutcome) -> dict[str, Any]:
        """Write the run's record (atomically, last: it is what marks the run finished)."""
        record = {
            "key": run.key,
            "index": run.index,
            "status": outcome.status,
            "error": outcome.error,
            "method": run.method,
            "labels": run.labels,
            "params": run.params,
            "repetition": run.repetition,
            "recipe_file": run.origin,
            "overrides": list(run.overrides),
            "max_frames": run.max_frames,
            "wall_seconds": outcome.wall_seconds,
            "host": outcome.host,
            "code": outcome.code,
        }
        write_atomically(folder / RECORD_FILE, json.dumps(record, indent=2, default=str) + "\n")
        return record

    @staticmethod
    def read_record(folder: Path) -> dict[str, Any] | None:
        try:
            return json.loads((folder / RECORD_FILE).read_text())
        except (OSError, ValueError):
            return None

    @staticmethod
    def read_metrics(folder: Path) -> dict[str, Any]:
        try:
            return json.loads((folder / METRICS_FILE).read_text())
        except (OSError, ValueError):
            return {}
