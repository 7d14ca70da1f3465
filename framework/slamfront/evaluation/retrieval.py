"""Descriptor retrieval: how often a correct reference is among a query's psi nearest
reference descriptors, for psi = 1..K (Rodrigues 2019 §4.2, figs 4.1 and 4.2).

It measures the descriptor alone, before any place map or sequence logic: Rodrigues 2019
uses it to show that its preprocessing retrieves more correct images. Every run with a
global descriptor and a paired source reports it; ``slamfront retrieval`` overlays the
curves of several descriptor settings (with and without preprocessing, say).

The curve is exact: every query against every reference, through the framework's
distance engine (:func:`slamfront.core.distances.k_nearest`, which for float32 L1 ranks
with a vectorised bound and re-ranks the few rows near the cut with the exact distances,
so the neighbours are those of the full distance matrix, ties included).
"""

from __future__ import annotations

import numpy as np

from slamfront.core.distances import k_nearest
from slamfront.core.loops import LoopGroundTruth, recall_at_k
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.messages import Features, FrameInfo, Message
from slamfront.report import plots

MAX_PAIRS = 200_000_000
"""Above this many query x reference pairs the brute-force curve is skipped (it would take
tens of seconds to minutes: 3,576 x 3,576 RST-SHelo pairs take about 1 s)."""


def retrieval_curve(
    reference_frames: np.ndarray,
    reference_vectors: np.ndarray,
    query_frames: np.ndarray,
    query_vectors: np.ndarray,
    truth: LoopGroundTruth,
    metric: str,
    max_k: int,
) -> np.ndarray:
    """(max_k,) recall: fraction of queries with a true match that have a correct reference
    among their psi nearest reference descriptors, for psi = 1..max_k (exact, brute force)."""
    nearest = k_nearest(query_vectors, reference_vectors, max_k, metric)  # type: ignore[arg-type]
    candidates = [reference_frames[row] for row in nearest]
    scores = recall_at_k(query_frames, candidates, truth, list(range(1, max_k + 1)))
    return np.array([scores[k] for k in range(1, max_k + 1)], dtype=np.float64)


class DescriptorRetrieval(Evaluation):
    """Recall of the psi nearest reference descriptors, psi = 1..``eval.retrieval_max_k``."""

    title = "Descriptor retrieval"

    def __init__(self) -> None:
        self._traversal: dict[int, str] = {}
        self._vectors: dict[int, np.ndarray] = {}
        self._metric = "l2"

    def observe(self, kind: str, message: Message) -> None:
        if isinstance(message, FrameInfo):
            self._traversal[message.frame] = message.traversal
        elif kind == "descriptor" and isinstance(message, Features) and message.vector is not None:
            self._vectors[message.frame] = message.vector
            self._metric = message.metric

    def curve(self, truth: LoopGroundTruth, max_k: int) -> tuple[np.ndarray, int, int] | None:
        """``(curve, n queries, n references)`` of what was observed; None when there is nothing to rank."""
        reference = np.array(
            sorted(f for f, t in self._traversal.items() if t == "reference" and f in self._vectors), dtype=np.int64
        )
        queries = np.array([int(f) for f in truth.queries if int(f) in self._vectors], dtype=np.int64)
        if max_k == 0 or len(reference) == 0 or len(queries) == 0:
            return None
        curve = retrieval_curve(
            reference, np.stack([self._vectors[f] for f in reference]), queries,
            np.stack([self._vectors[f] for f in queries]), truth, self._metric, max_k,
        )
        return curve, len(queries), len(reference)

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        max_k = context.options.retrieval_max_k
        truth = context.source.loop_ground_truth()
        if truth is None:
            return None
        n_reference = sum(1 for f, t in self._traversal.items() if t == "reference" and f in self._vectors)
        if len(truth) * n_reference > MAX_PAIRS:
            return EvaluationReport(self.title, markdown=(
                f"Skipped: {len(truth)} queries x {n_reference} references is too many for brute force.\n"
            ))
        result = self.curve(truth, max_k)
        if result is None:
            return None
        curve, n_queries, n_reference = result
        shown = [k for k in (1, 5, 10, 20) if k <= max_k]
        metrics = {f"retrieval_recall_at_{k}": float(curve[k - 1]) for k in shown}
        metrics["retrieval_recall_curve"] = [round(float(v), 6) for v in curve]
        figures = []
        if context.options.plots:
            label = context.plugin_names.get("descriptor", "descriptor")
            path = plots.recall_curves(
                {label: (np.arange(1, max_k + 1), curve)}, context.out_dir / "retrieval.png",
                title="correct reference among the psi nearest descriptors",
            )
            figures.append(path.name)
        table = "\n".join(["| psi | recall |", "| --- | --- |", *(f"| {k} | {curve[k - 1]:.4f} |" for k in shown)])
        markdown = (
            f"Queries: {n_queries}, references: {n_reference}, distance: {self._metric}.\n\n{table}\n\n"
            + "".join(f"![{f}]({f})\n\n" for f in figures)
        )
        return EvaluationReport(self.title, metrics=metrics, markdown=markdown, figures=figures)


def descriptor_curve(
    recipe_path: str, overrides: list[str], max_k: int, max_frames: int | None = None, label: str = ""
) -> np.ndarray:
    """Run only a recipe's source and descriptor and return its retrieval curve.

    :param overrides: ``--set`` style overrides applied to the recipe first.
    :raises RecipeError: the recipe has no descriptor, or its source no loop ground truth.
    """
    from tqdm import tqdm

    from slamfront.errors import RecipeError
    from slamfront.plugin import StageInputs
    from slamfront.recipe import build_pipeline, load_recipe

    recipe, path = load_recipe(recipe_path, overrides)
    pipeline = build_pipeline(recipe, str(path))
    descriptor = pipeline.plugins.get("descriptor")
    if descriptor is None:
        raise RecipeError(f"{path}: the recipe has no descriptor stage to evaluate")
    truth = pipeline.source.loop_ground_truth()
    if truth is None:
        raise RecipeError(f"{path}: source {pipeline.source.name!r} has no loop ground truth")
    watcher = DescriptorRetrieval()
    total = len(pipeline.source) if max_frames is None else min(max_frames, len(pipeline.source))
    for n, frame in enumerate(tqdm(pipeline.source.frames(), total=total, desc=label or recipe.name, unit="frame")):
        if max_frames is not None and n >= max_frames:
            break
        watcher.observe("frames", FrameInfo(frame.index, frame.timestamp, frame.traversal, frame.sequence_index,
                                            frame.name, frame.image.shape[1], frame.image.shape[0]))
        for message in descriptor.process(StageInputs(frame=frame)):
            watcher.observe("descriptor", message)
    result = watcher.curve(truth, max_k)
    if result is None:
        raise RecipeError(f"{path}: no reference or no query frames were described (raise --max-frames)")
    return result[0]
