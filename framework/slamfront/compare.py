"""Comparing loop-closure methods: several recipes through one harness, one report.

``slamfront compare RECIPE... -o DIR`` is a campaign whose methods are the recipes
given: it writes a sweep file (``DIR/compare.yaml``) and runs it with
:func:`slamfront.campaign.run_campaign` (so runs resume, run in parallel and keep their
own logs under ``DIR/runs/``), then writes ``DIR/comparison.md``: one table with every
method's recall at 100 % precision and AUC-PR (at the source's tolerance and at the
extra tolerances the recipes score), its search space and speed, all precision-recall
curves on one plot, and each method's match plot.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from slamfront.campaign import run_campaign
from slamfront.campaign.backends import Backend
from slamfront.campaign.campaign import CampaignResult
from slamfront.campaign.store import CampaignStore
from slamfront.errors import RecipeError
from slamfront.evaluation.loops import PR_CURVE_FILE, read_pr_curve
from slamfront.outputs import write_atomically
from slamfront.recipe import find_recipe, parse_override, read_recipe_dict
from slamfront.report import plots
from slamfront.report.html import write_html

COMPARED_METRICS = (
    "recall_at_100p",
    "auc_pr",
    "precision_at_operating_point",
    "recall_at_operating_point",
    "n_accepted",
    "accept_threshold",
    "recall_at_100p_zeta1",
    "auc_pr_zeta1",
    "recall_at_1",
    "n_places_reference",
    "n_places_query",
    "n_searches",
    "seconds",
    "frames_per_second",
)


@dataclass
class ComparisonResult:
    """Where the comparison wrote its outputs."""

    campaign: CampaignResult
    report_path: Path
    figures: list[Path]


def comparison_sweep(recipes: Sequence[str], overrides: Sequence[str], name: str) -> dict[str, Any]:
    """The sweep (as a dict) running each recipe once, labelled by its name."""
    methods: dict[str, Any] = {}
    for given in recipes:
        path = find_recipe(given)
        label = str(read_recipe_dict(path).get("name", path.stem))
        if label in methods:
            raise RecipeError(f"{given}: two recipes are named {label!r}; give them different names")
        methods[label] = {"recipe": str(path.resolve()), "labels": {"method": label}}
    override_map = dict(parse_override(item, "--set") for item in overrides)
    return {
        "name": name,
        "description": "Loop-closure methods compared through one harness: " + ", ".join(methods),
        "recipes": methods,
        "set": override_map,
        "metrics": list(COMPARED_METRICS),
    }


def compare(
    recipes: Sequence[str],
    out_dir: Path,
    backend: Backend,
    overrides: Sequence[str] = (),
    *,
    max_frames: int | None = None,
    progress: bool | None = None,
    force: bool = False,
) -> ComparisonResult:
    """Run every recipe (skipping those already finished in ``out_dir``) and write the report."""
    if not recipes:
        raise RecipeError("compare needs at least one recipe")
    store = CampaignStore(out_dir.resolve())
    with store.locked():  # compare.yaml, the figures and the report too: one writer per folder
        sweep_path = out_dir / "compare.yaml"
        write_atomically(sweep_path, yaml.safe_dump(comparison_sweep(recipes, overrides, out_dir.name), sort_keys=False))
        campaign = run_campaign(
            sweep_path, out_dir, backend, force=force, progress=progress, max_frames=max_frames, held=store
        )
        rows = json.loads(campaign.results_json.read_text())["runs"]
        figures = _figures(rows, out_dir)
        report = _write_report(rows, figures, out_dir)
    return ComparisonResult(campaign, report, figures)


def _run_folder(row: dict[str, Any], out_dir: Path) -> Path:
    return out_dir / row["run"]


def _figures(rows: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    curves = {}
    figures: list[Path] = []
    for row in rows:
        folder = _run_folder(row, out_dir)
        if row["status"] != "ok" or not (folder / PR_CURVE_FILE).is_file():
            continue
        _, precision, recall = read_pr_curve(folder / PR_CURVE_FILE)
        curves[row["method"]] = (recall, precision)
        if (folder / "matches.png").is_file():
            target = out_dir / f"matches_{row['method']}.png"
            shutil.copyfile(folder / "matches.png", target)
            figures.append(target)
    if curves:
        figures.insert(0, plots.pr_curves(curves, out_dir / "pr_all.png", title="precision-recall, all methods"))
    return figures


def _cell(value: Any) -> str:
    if value is None or value == "":
        return "-"
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value)


def _write_report(rows: list[dict[str, Any]], figures: list[Path], out_dir: Path) -> Path:
    present = [m for m in COMPARED_METRICS if any(row.get(m) not in (None, "") for row in rows)]
    lines = [
        f"# Comparison: {out_dir.name}",
        "",
        "Each method is one recipe, run through the same harness and scored against the same "
        "ground truth (`recall_at_100p`/`auc_pr` at the source's tolerance, `_zeta1` at zeta = 1). "
        "`precision_at_operating_point`/`recall_at_operating_point`: of the `n_accepted` answers each detector "
        "accepts at its own threshold (`accept_threshold`), what a SLAM back end would consume. "
        "Runs and their logs are in `runs/` (each run's report is linked in the last column; "
        "[report.md](report.md) is the campaign's view); `results.csv` has the same numbers.",
        "",
        "| method | status | " + " | ".join(present) + " | run |",
        "| --- | --- |" + " --- |" * len(present) + " --- |",
    ]
    for row in rows:
        cells = [_cell(row.get(m)) for m in present]
        folder = _run_folder(row, out_dir)
        link = f"[report]({row['run']}/report.md)" if (folder / "report.md").is_file() else "-"
        lines.append(f"| {row['method']} | {row['status']} | " + " | ".join(cells) + f" | {link} |")
    failed = [row for row in rows if row["status"] == "failed"]
    if failed:
        lines += ["", "## Failed runs", ""] + [f"- {row['method']}: {row.get('error')}" for row in failed]
    lines.append("")
    for figure in figures:
        lines += [f"![{figure.stem}]({figure.name})", ""]
    path = out_dir / "comparison.md"
    write_atomically(path, "\n".join(lines))
    write_html(path)
    return path
