"""The framework's evaluations, chosen from the stages a recipe runs.

Each evaluation watches the run's messages and, at the end, produces metrics for
``metrics.json``, a section of ``report.md`` and plots. These score the shared message
contract (frames, descriptors, loop results); what a plugin's own messages mean is
scored by the evaluations its package contributes (``slamfront_evaluations``).
"""

from __future__ import annotations

from collections.abc import Iterable

from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.evaluation.frames import FrameOverview
from slamfront.evaluation.loops import LoopClosureEvaluation
from slamfront.evaluation.retrieval import DescriptorRetrieval


def evaluations_for(kinds: Iterable[str]) -> list[Evaluation]:
    """Fresh framework evaluations for a run whose recipe has the plugin kinds ``kinds``."""
    kinds = set(kinds)
    chosen: list[Evaluation] = [FrameOverview()]
    if "descriptor" in kinds:
        chosen.append(DescriptorRetrieval())
    if "loop_detector" in kinds:
        chosen.append(LoopClosureEvaluation())
    return chosen


__all__ = ["Evaluation", "EvaluationContext", "EvaluationReport", "evaluations_for"]
