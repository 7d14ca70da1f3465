"""``report.md``: what a person reads after a run."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from slamfront.evaluation.base import EvaluationReport
from slamfront.outputs import write_atomically
from slamfront.recipe import Recipe
from slamfront.report.headline import headline


def write_report(
    out_dir: Path,
    recipe: Recipe,
    origin: str,
    metrics: dict[str, Any],
    sections: Sequence[EvaluationReport],
    announce: Callable[[Path, int, str], None] | None = None,
) -> Path:
    """Write ``out_dir/report.md`` and return its path (``announce``: see
    :func:`slamfront.outputs.write_atomically`)."""
    lines = [f"# {recipe.name}", ""]
    if recipe.description:
        lines += [recipe.description.strip(), ""]
    lines += [f"Recipe: `{origin}`. Log: `run.mcap` (open it in Foxglove). Metrics: `metrics.json`.", ""]
    lines += ["## Headline", "", *(f"- {sentence}" for sentence in headline(metrics)), "",
              "Every number of the run, with what it means, is in the sections below and in `metrics.json`.", ""]
    for section in sections:
        lines += [f"## {section.title}", "", section.markdown.rstrip(), ""]
    timing = metrics.get("timing", {})
    if timing:
        lines += [
            "## Time per stage",
            "",
            "| stage | median ms/frame | p99 ms/frame | total s | at finish s |",
            "| --- | --- | --- | --- | --- |",
        ]
        for kind, row in timing.items():
            lines.append(
                f"| {kind} | {row['median_ms']:.3f} | {row['p99_ms']:.3f} | {row['total_s']:.3f} | {row['finish_s']:.3f} |"
            )
        lines.append("")
    lines += ["## Recipe", "", "```yaml", recipe.to_yaml().rstrip(), "```", ""]
    return write_atomically(out_dir / "report.md", "\n".join(lines), announce)
