"""``report.md``: what a person reads after a run."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from slamfront.evaluation.base import EvaluationReport
from slamfront.outputs import write_atomically
from slamfront.recipe import Recipe

_HEADLINE_KEYS = (
    "recall_at_100p",
    "auc_pr",
    "ate_rmse_m",
    "rpe_rmse_m",
    "ate_rmse_before_m",
    "ate_rmse_after_m",
    "drift_before_m",
    "drift_after_m",
    "n_loop_constraints_added",
    "n_loop_constraints_added_false",
    "precision_verified",
    "recall_verified",
    "n_queries",
    "n_searches",
    "n_places_reference",
    "n_places_query",
    "n_keyframes",
    "n_clouds",
    "n_frames",
    "seconds",
    "frames_per_second",
)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def write_report(
    out_dir: Path, recipe: Recipe, origin: str, metrics: dict[str, Any], sections: Sequence[EvaluationReport]
) -> Path:
    """Write ``out_dir/report.md`` and return its path."""
    lines = [f"# {recipe.name}", ""]
    if recipe.description:
        lines += [recipe.description.strip(), ""]
    lines += [f"Recipe: `{origin}`. Log: `run.mcap` (open it in Foxglove). Metrics: `metrics.json`.", ""]
    lines += ["## Headline", "", "| metric | value |", "| --- | --- |"]
    lines += [f"| {key} | {_fmt(metrics[key])} |" for key in _HEADLINE_KEYS if key in metrics]
    lines.append("")
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
    return write_atomically(out_dir / "report.md", "\n".join(lines))
