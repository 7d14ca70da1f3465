"""A campaign's ``report.md`` and ``report.html``: counts, the results table (each run linked
to its own report), the failures and the figures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from slamfront.campaign.plan import short_name
from slamfront.campaign.results import ResultsTable, cell
from slamfront.campaign.sweepfile import Sweep
from slamfront.outputs import write_atomically
from slamfront.report.html import write_html


def _shown(value: object) -> str:
    text = f"{value:.4g}" if isinstance(value, float) else cell(value)
    return text.replace("|", "\\|")


def write_campaign_report(
    out_dir: Path, sweep: Sweep, sweep_path: Path, table: ResultsTable, figures: Sequence[Path], n_skipped: int
) -> Path:
    """Write ``out_dir/report.md`` and return its path."""
    statuses = [row["status"] for row in table.rows]
    counts = ", ".join(f"{statuses.count(s)} {s}" for s in ("ok", "failed", "pending") if statuses.count(s))
    lines = [f"# Campaign {sweep.name}", ""]
    if sweep.description:
        lines += [sweep.description.strip(), ""]
    lines += [
        f"Sweep: `{sweep_path}`. {len(table.rows)} runs: {counts}"
        + (f" ({n_skipped} finished before this invocation, not run again)" if n_skipped else "") + ".",
        "Each run's log, metrics and report are in its folder under `runs/`; the table is also in",
        "`results.csv` and `results.json`.",
        "",
    ]
    missing = table.missing_metrics()
    if missing:
        lines += [f"No finished run reported: {', '.join(missing)}.", ""]
    columns = ["run", "status", *table.factor_columns, *table.metric_columns, "seconds"]
    headers = [short_name(c) for c in columns]
    lines += ["## Results", "", "| " + " | ".join(headers) + " |", "|" + " --- |" * len(columns)]
    for row in table.rows:
        shown = [f"[{Path(row['run']).name}]({row['run']}/report.md)" if row["status"] == "ok" else row["run"],
                 *(_shown(row.get(c)) for c in columns[1:])]
        lines.append("| " + " | ".join(shown) + " |")
    failed = [row for row in table.rows if row["status"] == "failed"]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- `{row['run']}`: {row['error']}" for row in failed]
    if figures:
        lines += ["", "## Figures", ""]
        lines += [f"![{p.name}]({p.relative_to(out_dir).as_posix()})\n" for p in figures]
    path = out_dir / "report.md"
    write_atomically(path, "\n".join(lines).rstrip() + "\n")
    write_html(path)  # report.html beside it, its links to the runs' reports pointing at their pages
    return path
