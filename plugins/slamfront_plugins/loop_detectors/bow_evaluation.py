"""Bag-of-words detector report: the Wang et al. 2017 figures from the detector's per-frame statistics.

Fig. 4 (vocabulary size over time, both update rules when the detector tracks the
other one), fig. 6 (mean quantisation error per image), fig. 7 (largest loop
posterior over time) and fig. 9 (working-memory size; processing time per image
against the time budget), plus their summary numbers for ``metrics.json``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.messages import Message
from slamfront.report import plots
from slamfront_plugins.loop_detectors.bow_messages import BowStatistics

_FIELDS = (
    "frame", "n_features", "vocabulary_size", "active_words", "quantisation_error", "other_vocabulary_size",
    "other_quantisation_error", "merged", "wm_size", "stm_size", "ltm_size", "transferred", "retrieved",
    "no_loop_posterior", "max_loop_posterior", "processing_seconds", "modelled_seconds",
    "by_ratio_test", "by_nd_high",
)


class BowEvaluation(Evaluation):
    """Collects ``BowStatistics`` (a few numbers per frame) and plots them at the end."""

    title = "Bag of words, Bayes filter and memory"

    def __init__(self) -> None:
        self._rows: list[tuple[float, ...]] = []
        self._last: BowStatistics | None = None

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, BowStatistics):
            self._rows.append(tuple(float(getattr(message, name)) for name in _FIELDS))
            self._last = message

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        if self._last is None:
            return None
        last = self._last
        table = np.array(self._rows, dtype=np.float64)
        col = {name: table[:, k] for k, name in enumerate(_FIELDS)}
        tracked_other = bool(last.other_rule)
        milliseconds = col["processing_seconds"] * 1000.0
        budget = last.time_budget_seconds
        modelled = bool(np.isfinite(col["modelled_seconds"]).any())
        # what the budget was compared with: the time model's seconds when there is one
        compared = col["modelled_seconds"] if modelled else col["processing_seconds"]
        metrics: dict[str, Any] = {
            "bow_update_rule": last.update_rule,
            "bow_vocabulary_size": int(last.vocabulary_size),
            "bow_active_words": int(last.active_words),
            "bow_mean_quantisation_error": _nanmean(col["quantisation_error"]),
            "bow_merged_frames": int(col["merged"].sum()),
            # which test decided the features: the greedy rule's band should leave most to the ratio test
            "bow_share_ratio_test": feature_share(col["by_ratio_test"], col["n_features"]),
            "bow_share_nd_high": feature_share(col["by_nd_high"], col["n_features"]),
            "bow_wm_size_max": int(col["wm_size"].max()),
            "bow_wm_size_final": int(last.wm_size),
            "bow_ltm_size_final": int(last.ltm_size),
            "bow_transferred": int(col["transferred"].sum()),
            "bow_retrieved": int(col["retrieved"].sum()),
            "bow_processing_ms_median": float(np.median(milliseconds)),
            "bow_processing_ms_p99": float(np.percentile(milliseconds, 99)),
            "bow_time_budget_ms": budget * 1000.0,
            "bow_time_model": "linear" if modelled else "wall",
            "bow_frames_over_budget": int(np.sum(compared > budget)) if budget > 0 else 0,
            "bow_frames_transferring": int(np.sum(col["transferred"] > 0)),
        }
        if modelled:
            metrics["bow_modelled_ms_median"] = float(np.nanmedian(col["modelled_seconds"]) * 1000.0)
            metrics["bow_modelled_ms_p99"] = float(np.nanpercentile(col["modelled_seconds"], 99) * 1000.0)
        if tracked_other:
            metrics["bow_other_rule"] = last.other_rule
            metrics["bow_other_vocabulary_size"] = int(last.other_vocabulary_size)
            metrics["bow_other_mean_quantisation_error"] = _nanmean(col["other_quantisation_error"])
        figures = []
        if context.options.plots:
            figures = self._plots(context, col, last)
        lines = ["| metric | value |", "| --- | --- |"]
        lines += [f"| {key} | {_fmt(value)} |" for key, value in metrics.items()]
        markdown = "\n".join(lines) + "\n\n" + "".join(f"![{f}]({f})\n\n" for f in figures)
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)

    def _plots(self, context: EvaluationContext, col: dict[str, np.ndarray], last: BowStatistics) -> list[str]:
        x = col["frame"]
        out = context.out_dir
        rule, other = last.update_rule, last.other_rule
        vocabulary = {f"{rule} (kept)": (x, col["vocabulary_size"]), f"{rule} (searched)": (x, col["active_words"])}
        error = {rule: (x, col["quantisation_error"])}
        if other:
            vocabulary[f"{other} (kept)"] = (x, col["other_vocabulary_size"])
            error[other] = (x, col["other_quantisation_error"])
        paths = [
            plots.series_panels([("words", vocabulary, {})], out / "bow_vocabulary.png",
                                "vocabulary size over time (Wang et al. 2017, fig. 4)"),
            plots.series_panels([("mean quantisation error", error, {})], out / "bow_quantisation.png",
                                "mean quantisation error per image (Wang et al. 2017, fig. 6)"),
            plots.series_panels(
                [(
                    "posterior",
                    {"max p(S_t = i)": (x, col["max_loop_posterior"]), "1 - p(S_t = -1)": (x, 1.0 - col["no_loop_posterior"])},
                    {} if np.isnan(last.loop_threshold) else {"accept: 1 - T_loop": 1.0 - last.loop_threshold},
                )],
                out / "bow_posterior.png", "largest loop posterior over time (Wang et al. 2017, fig. 7)",
            ),
            plots.series_panels(
                [
                    ("places", {"WM (searched)": (x, col["wm_size"]), "LTM": (x, col["ltm_size"])}, {}),
                    (
                        "ms per image",
                        {"detector time": (x, col["processing_seconds"] * 1000.0)}
                        | ({"modelled time": (x, col["modelled_seconds"] * 1000.0)}
                           if np.isfinite(col["modelled_seconds"]).any() else {}),
                        {"time budget": last.time_budget_seconds * 1000.0} if last.time_budget_seconds > 0 else {},
                    ),
                ],
                out / "bow_memory.png", "working memory and processing time (Wang et al. 2017, fig. 9)",
            ),
        ]
        return [p.name for p in paths]


def feature_share(counts: np.ndarray, features: np.ndarray) -> float | None:
    """Share of the quantised features (frames with a count) that ``counts`` covers."""
    known = counts >= 0
    return float(counts[known].sum() / features[known].sum()) if features[known].sum() > 0 else None


def _nanmean(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if len(finite) else None


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)

