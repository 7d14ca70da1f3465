"""The campaign's results table: one row per run, in plan order, as CSV and JSON.

Columns: ``run`` (its folder), ``status`` (ok / failed / pending), the factors (``method``,
labels such as ``variant``, one column per varied override path, ``repetition``), the
metrics the sweep asked for, the timing columns, the ``error`` and the run's ``key``.
Rows are in plan order whatever order runs finished in, so two executions of one sweep
give the same table except for the timing columns.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slamfront.campaign.plan import PlannedRun, format_value
from slamfront.campaign.sweepfile import Sweep
from slamfront.outputs import write_atomically

TIMING_COLUMNS = ("seconds", "wall_seconds")
"""Wall-clock columns: they differ between executions of the same run."""


def is_timing(column: str) -> bool:
    return column in TIMING_COLUMNS or column == "frames_per_second" or column.startswith("timing.")


def metric_value(metrics: Mapping[str, Any], name: str) -> Any:
    """``metrics[name]``, where a dotted name walks nested dicts (``timing.descriptor.median_ms``)."""
    if name in metrics:
        return metrics[name]
    node: Any = metrics
    for part in name.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


@dataclass
class ResultsTable:
    """Rows of plain values plus which columns are factors, metrics and timings."""

    columns: list[str]
    label_columns: list[str]
    """``variant`` and the methods' labels."""
    param_columns: list[str]
    """The varied override paths."""
    metric_columns: list[str]
    rows: list[dict[str, Any]]
    repetitions: bool = False
    all_metrics: list[dict[str, Any]] = field(default_factory=list)
    """Each run's whole metrics.json (empty for runs that did not finish), same order as rows."""

    @property
    def factor_columns(self) -> list[str]:
        return ["method", *self.label_columns, *self.param_columns, *(["repetition"] if self.repetitions else [])]

    @property
    def timing_columns(self) -> list[str]:
        return [c for c in self.columns if is_timing(c)]

    def missing_metrics(self) -> list[str]:
        """Requested metrics no finished run reported (probably a typo, or the wrong stage)."""
        ok = [row for row in self.rows if row["status"] == "ok"]
        return [m for m in self.metric_columns if ok and all(row.get(m) is None for row in ok)]


def build_table(
    sweep: Sweep,
    runs: Sequence[PlannedRun],
    folders: Mapping[str, Path],
    records: Mapping[str, Mapping[str, Any]],
    metrics: Mapping[str, Mapping[str, Any]],
    root: Path,
) -> ResultsTable:
    """The table for ``runs``; a run without a record is ``pending``.

    :param folders: run folder by key; ``records`` and ``metrics`` likewise.
    :param root: the campaign folder (run folders are shown relative to it).
    """
    label_columns: list[str] = []
    for run in runs:
        label_columns += [k for k in run.labels if k not in label_columns]
    param_columns = sweep.parameter_paths()
    metric_columns = [m for m in sweep.metrics if m not in TIMING_COLUMNS]
    table = ResultsTable([], label_columns, param_columns, metric_columns, [], sweep.repetitions > 1)
    table.columns = ["run", "status", *table.factor_columns, *metric_columns, *TIMING_COLUMNS, "error", "key"]
    for run in runs:
        record = records.get(run.key, {})
        values = metrics.get(run.key, {})
        folder = folders.get(run.key, root / "runs" / run.name)
        row: dict[str, Any] = {
            "run": folder.relative_to(root).as_posix() if folder.is_relative_to(root) else str(folder),
            "status": record.get("status", "pending"),
            "method": run.method,
            **{k: run.labels.get(k) for k in label_columns},
            **{p: run.params.get(p) for p in param_columns},
        }
        if table.repetitions:
            row["repetition"] = run.repetition
        row.update({m: metric_value(values, m) for m in metric_columns})
        row.update({"seconds": values.get("seconds"), "wall_seconds": record.get("wall_seconds")})
        row.update({"error": record.get("error", ""), "key": run.key})
        table.rows.append(row)
        table.all_metrics.append(dict(values))
    return table


def cell(value: Any) -> str:
    """A CSV cell: floats in full precision, other values as flow YAML, None as empty."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, float):
        return repr(value)
    return format_value(value)


def write_csv(table: ResultsTable, path: Path) -> Path:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(table.columns)
    for row in table.rows:
        writer.writerow([cell(row.get(c)) for c in table.columns])
    return write_atomically(path, buffer.getvalue())


def write_json(table: ResultsTable, sweep: Sweep, sweep_path: Path, path: Path) -> Path:
    document = {
        "sweep": sweep.name,
        "sweep_file": str(sweep_path),
        "description": sweep.description,
        "columns": table.columns,
        "factor_columns": table.factor_columns,
        "metric_columns": table.metric_columns,
        "timing_columns": table.timing_columns,
        "runs": [{**row, "metrics": values} for row, values in zip(table.rows, table.all_metrics)],
    }
    return write_atomically(path, json.dumps(document, indent=2, default=str) + "\n")
