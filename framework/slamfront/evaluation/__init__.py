"""Built-in evaluations, chosen from the stages a recipe runs.

Each evaluation watches the run's messages and, at the end, produces metrics for
``metrics.json``, a section of ``report.md`` and plots.
"""

from __future__ import annotations

from slamfront.evaluation.backend import BackendEvaluation
from slamfront.evaluation.base import Evaluation, EvaluationContext, EvaluationReport
from slamfront.evaluation.bow import BowEvaluation
from slamfront.evaluation.frames import FrameOverview
from slamfront.evaluation.localization import LocalizationEvaluation
from slamfront.evaluation.loops import LoopClosureEvaluation
from slamfront.evaluation.registration import RegistrationEvaluation
from slamfront.evaluation.retrieval import DescriptorRetrieval
from slamfront.plugin import Kind


def evaluations_for(kinds: set[Kind]) -> list[Evaluation]:
    """Fresh evaluations for a run whose recipe has the stages ``kinds``."""
    chosen: list[Evaluation] = [FrameOverview()]
    if "descriptor" in kinds:
        chosen.append(DescriptorRetrieval())
    if "loop_detector" in kinds:
        chosen.append(LoopClosureEvaluation())
        chosen.append(BowEvaluation())  # reports only when a detector emits BowStatistics
    if "registration" in kinds:
        chosen.append(RegistrationEvaluation())
    if "localizer" in kinds:
        chosen.append(LocalizationEvaluation())
    if "backend" in kinds:
        chosen.append(BackendEvaluation())
    return chosen


__all__ = ["Evaluation", "EvaluationContext", "EvaluationReport", "evaluations_for"]
