"""Loop-closure evaluation: precision-recall, recall at 100 % precision, AUC-PR, recall@K,
the search-space table, and the match plot (chosen reference vs query over the
ground-truth band).

Two scoring options (``eval.loop_scoring``, ``eval.unsearched_frames``), whose defaults
score every frame's match frame: ``place`` counts a match correct when any frame of the
matched place is (detectors that merge frames into places list them in
``LoopResult.match_frames``); ``exclude`` leaves out the frames a detector answered
without searching. The report and ``metrics.json`` say which rule scored the run.

Scores are computed at the source's own tolerance and, for sources that can change it
(``Source.loop_ground_truth_at``), at every extra tolerance in ``eval.tolerances``
(metrics suffixed ``_zeta<t>``), so one run gives, say, zeta = 3 and zeta = 1.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slamfront.core.loops import LoopGroundTruth, PrecisionRecall, precision_recall, recall_at_k
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.messages import FrameInfo, LoopResult, LoopVerdict, Message
from slamfront.outputs import write_atomically
from slamfront.recipe import EvalOptions
from slamfront.report import plots

PR_CURVE_FILE = "pr_curve.csv"
"""The run's precision-recall curve beside metrics.json, for campaigns comparing runs."""


def write_pr_curve(curve: PrecisionRecall, path: Path) -> Path:
    """One row per threshold (decreasing): ``threshold,precision,recall``, full float precision."""
    rows = (f"{t!r},{p!r},{r!r}" for t, p, r in zip(curve.thresholds.tolist(), curve.precision.tolist(),
                                                     curve.recall.tolist()))
    return write_atomically(path, "\n".join(["threshold,precision,recall", *rows]) + "\n")


def read_pr_curve(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(threshold, precision, recall)`` arrays from a file :func:`write_pr_curve` wrote."""
    lines = path.read_text().splitlines()[1:]
    table = np.array([[float(v) for v in line.split(",")] for line in lines if line], dtype=np.float64)
    table = table.reshape(-1, 3)
    return table[:, 0], table[:, 1], table[:, 2]


_PER_TOLERANCE = ("recall_at_100p", "auc_pr", "n_queries_with_true_match", "threshold_at_100p",
                  "precision_at_operating_point", "recall_at_operating_point", "n_accepted", "correct_answer_ceiling")


@dataclass
class _Scores:
    metrics: dict[str, Any]
    curve: PrecisionRecall
    correct: np.ndarray
    truth: LoopGroundTruth
    """The ground truth of the queries scored (unsearched ones left out under ``exclude``)."""


def score_loops(
    reported: Mapping[int, LoopResult], truth: LoopGroundTruth, ks: list[int], options: EvalOptions
) -> _Scores:
    """Score a detector's answers (by query frame) against the ground truth, by the options' rule.

    The metrics are those of ``metrics.json`` (recall at 100 % precision, AUC-PR, recall@K,
    the operating point) plus the rule used (``loop_scoring``, ``unsearched_frames``) and
    how many queries it left out.
    """
    missing = LoopResult(frame=-1, match=-1, confidence=float("nan"), accepted=False, reason="not reported")
    excluded = 0
    if options.unsearched_frames == "exclude":
        kept = np.array([reported.get(int(f), missing).searched for f in truth.queries], dtype=bool)
        excluded = int((~kept).sum())
        truth = truth.subset(kept)
    frames = truth.queries
    results = [reported.get(int(f), missing) for f in frames]
    match = np.array([r.match for r in results], dtype=np.int64)
    confidence = np.array([r.confidence for r in results], dtype=np.float64)
    accepted = np.array([r.accepted for r in results], dtype=bool)
    answered = match >= 0
    if options.loop_scoring == "place":
        correct = truth.is_correct_place(frames, match, [r.match_frames for r in results])
    else:
        correct = truth.is_correct(frames, match)
    positives = truth.has_true_match()
    curve = precision_recall(confidence, answered, correct, int(positives.sum()))
    op_accepted = accepted & answered
    op_tp = int(np.sum(op_accepted & correct))
    metrics: dict[str, Any] = {
        "recall_at_100p": curve.recall_at_100p,
        "auc_pr": curve.auc,
        "n_queries": int(len(frames)),
        "n_queries_with_true_match": int(positives.sum()),
        "n_answered": int(answered.sum()),
        "n_not_reported": int(sum(1 for f in frames if int(f) not in reported)),
        "loop_scoring": options.loop_scoring,
        "unsearched_frames": options.unsearched_frames,
        "n_queries_excluded": excluded,
        "threshold_at_100p": curve.threshold_at_100p(),
        # what any confidence could reach: recall@100%P <= this, equal when every
        # correct answer is more confident than every wrong one
        "correct_answer_ceiling": int(np.sum(answered & correct)) / max(int(positives.sum()), 1),
        "answered_of_answerable": int(np.sum(answered & positives)) / max(int(positives.sum()), 1),
        # the closures a SLAM back end would consume: those the detector accepts at its own threshold
        "precision_at_operating_point": op_tp / max(int(op_accepted.sum()), 1),
        "recall_at_operating_point": op_tp / max(int(positives.sum()), 1),
        "n_accepted": int(op_accepted.sum()),
    }
    candidates = [r.candidates for r in results]
    if any(c is not None for c in candidates):
        for k, value in recall_at_k(frames, candidates, truth, ks).items():
            metrics[f"recall_at_{k}"] = value
    return _Scores(metrics, curve, correct, truth)


class LoopClosureEvaluation(Evaluation):
    """Scores every ``LoopResult`` against the source's loop ground truth."""

    title = "Loop closure"

    def __init__(self) -> None:
        self._results: dict[int, LoopResult] = {}
        self._sequence_index: dict[int, tuple[str, int]] = {}
        self._verified: dict[int, int] = {}
        """Query frame -> match of the loop closures a back end verified and added."""
        self._has_backend = False

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, LoopResult):
            self._results[message.frame] = message
        elif isinstance(message, FrameInfo):
            self._sequence_index[message.frame] = (message.traversal, message.sequence_index)
        elif isinstance(message, LoopVerdict):  # a back end's decision on a closure
            self._has_backend = True
            if message.added:
                self._verified[message.frame] = message.match

    def _verified_point(self, truth: LoopGroundTruth) -> dict[str, Any]:
        """Precision and recall of the closures the back end verified (geometrically) and
        added, over the same queries as the detector's own operating point."""
        queries = set(truth.queries.tolist())
        known = [(f, m) for f, m in self._verified.items() if f in queries]
        frames = np.array([f for f, _ in known], dtype=np.int64)
        matches = np.array([m for _, m in known], dtype=np.int64)
        tp = int(truth.is_correct(frames, matches).sum()) if len(known) else 0
        positives = int(truth.has_true_match().sum())
        return {
            "n_verified": len(known),
            "precision_verified": tp / len(known) if known else float("nan"),
            "recall_verified": tp / max(positives, 1),
        }

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        truth = context.source.loop_ground_truth()
        if truth is None:
            return EvaluationReport(self.title, markdown="The source has no loop ground truth: nothing to score.\n")
        zeta = getattr(context.source.config, "tolerance", None)
        if zeta is not None and context.source.loop_ground_truth_at(zeta) is None:
            zeta = None  # the source's truth is not a band of frames (a stream's revisit radius)
        main = score_loops(self._results, truth, context.options.recall_at_k, context.options)
        write_pr_curve(main.curve, context.out_dir / PR_CURVE_FILE)
        metrics = dict(main.metrics)
        label = context.plugin_names.get("loop_detector", "detector")
        curves = {label + (f" (zeta={zeta})" if zeta is not None else ""): (main.curve.recall, main.curve.precision)}
        notes = []
        for tolerance in context.options.tolerances:
            other_truth = context.source.loop_ground_truth_at(tolerance)
            if other_truth is None:
                notes.append(f"The source cannot be scored at tolerance {tolerance} (no tolerance to change).")
                continue
            other = score_loops(self._results, other_truth, context.options.recall_at_k, context.options)
            for key, value in other.metrics.items():
                if key in _PER_TOLERANCE or (key.startswith("recall_at_") and key[len("recall_at_"):].isdigit()):
                    metrics[f"{key}_zeta{tolerance}"] = value
            curves[f"{label} (zeta={tolerance})"] = (other.curve.recall, other.curve.precision)
        if self._has_backend:
            metrics.update(self._verified_point(truth))
        space = self._search_space(context)
        metrics.update({k: v for k, v in space.items() if k not in context.statistics})

        figures = []
        if context.options.plots:
            figures = self._plots(context, curves, main, main.truth, metrics)
        table = "\n".join(
            ["| metric | value |", "| --- | --- |", *(f"| {key} | {_fmt(value)} |" for key, value in metrics.items())]
        )
        search = self._search_space_table({**space, **{k: context.statistics[k] for k in space if k in context.statistics}})
        markdown = (
            f"{table}\n\n{_scoring_note(context.options, metrics)}\n\n" + "".join(f"{note}\n\n" for note in notes) + search + "\n\n"
            + "".join(f"![{name}]({name})\n\n" for name in figures)
        )
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)

    def _search_space(self, context: EvaluationContext) -> dict[str, int]:
        """Rodrigues 2019 Table 4.4. Detectors without places search every frame: places = frames.

        A stream (one traversal that revisits itself) has no reference and query halves: its
        frames and places are counted as the stream's, never as a reference of 0 frames.
        """
        n_reference = sum(1 for t, _ in self._sequence_index.values() if t == "reference")
        n_query = sum(1 for t, _ in self._sequence_index.values() if t == "query")
        n_stream = sum(1 for t, _ in self._sequence_index.values() if t == "stream")
        answered = sum(1 for r in self._results.values() if r.match >= 0)
        if n_stream and not n_reference:
            return {"n_frames_stream": n_stream, "n_places_stream": n_stream, "n_searches": answered}
        return {
            "n_frames_reference": n_reference,
            "n_frames_query": n_query + n_stream,
            "n_places_reference": n_reference,
            "n_places_query": n_query + n_stream,
            "n_searches": answered,
        }

    @staticmethod
    def _search_space_table(space: dict[str, int]) -> str:
        if "n_frames_stream" in space:
            header = "| frames in the stream | places | searches for a loop |"
            row = f"| {space['n_frames_stream']} | {space['n_places_stream']} | {space['n_searches']} |"
        else:
            header = "| frames per traversal (ref / query) | reference places | query places | searches for a loop |"
            row = (f"| {space['n_frames_reference']} / {space['n_frames_query']} | {space['n_places_reference']} | "
                   f"{space['n_places_query']} | {space['n_searches']} |")
        rule = "|" + " --- |" * (header.count("|") - 1)
        return "\n".join(["Search space (Rodrigues 2019 Table 4.4):", "", header, rule, row])

    def _plots(self, context, curves, main: _Scores, truth: LoopGroundTruth, metrics) -> list[str]:  # type: ignore[no-untyped-def]
        curve = main.curve
        points = {"accepted by the detector": (metrics["recall_at_operating_point"],
                                               metrics["precision_at_operating_point"])}
        if metrics.get("n_verified"):
            points["verified by the back end"] = (metrics["recall_verified"], metrics["precision_verified"])
        pr_path = plots.pr_curves(
            curves,
            context.out_dir / "pr.png",
            title=f"precision-recall (recall@100%P = {curve.recall_at_100p:.3f}, AUC = {curve.auc:.3f})",
            points=points,
        )
        frames = truth.queries
        results = [self._results.get(int(f)) for f in frames]
        match = np.array([-1 if r is None else r.match for r in results])
        confidence = np.array([np.nan if r is None else r.confidence for r in results], dtype=np.float64)
        accepted = np.array([r is not None and r.accepted for r in results], dtype=bool)

        def seq(frame_indices: np.ndarray) -> np.ndarray:
            return np.array(
                [self._sequence_index.get(int(f), ("", np.nan))[1] if f >= 0 else np.nan for f in frame_indices],
                dtype=np.float64,
            )

        lo = np.full(len(frames), np.nan)
        hi = np.full(len(frames), np.nan)
        rows = truth.rows_of(frames)
        for k, row in enumerate(rows):
            span = truth.matches[truth.indptr[row] : truth.indptr[row + 1]]
            if len(span):
                lo[k], hi[k] = seq(span[:1])[0], seq(span[-1:])[0]
        match_path = plots.match_plot(
            query=seq(frames),
            match=seq(match),
            confidence=confidence,
            correct=main.correct,
            truth_lo=lo,
            truth_hi=hi,
            path=context.out_dir / "matches.png",
            title="chosen match vs query (green: ground truth band)",
            accepted=accepted,
        )
        return [pr_path.name, match_path.name]


def _scoring_note(options: EvalOptions, metrics: dict[str, Any]) -> str:
    """One sentence naming the scoring rule, for the report."""
    rule = (
        "a match is correct when any frame of the matched place is a true match (place scoring)"
        if options.loop_scoring == "place"
        else "a match is correct when its match frame is a true match (frame scoring)"
    )
    unsearched = (
        f"frames answered without a search are left out ({metrics['n_queries_excluded']} frames)"
        if options.unsearched_frames == "exclude"
        else "every frame is scored, searched or not"
    )
    return f"Scoring: {rule}; {unsearched}."


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    return str(value)
