"""Built-in loop detectors, their own messages and the bag-of-words evaluation."""

from slamfront import hookimpl
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes
from slamfront_plugins.loop_detectors.hierarchical_faithful import HierarchicalFaithful
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from slamfront_plugins.loop_detectors.seqslam import SeqSlam, SeqSlamFast


@hookimpl
def slamfront_loop_detectors() -> list[type]:
    return [NearestNeighbour, HierarchicalSequence, HierarchicalFaithful, SeqSlam, SeqSlamFast, BowBayes]


@hookimpl
def slamfront_message_types() -> list[type]:
    from slamfront_plugins.loop_detectors.bow_messages import BowStatistics
    from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision
    from slamfront_plugins.loop_detectors.hierarchical_records import SequenceDecision

    return [BowStatistics, SequenceDecision, FaithfulSequenceDecision]


@hookimpl
def slamfront_evaluations(kinds: frozenset[str]) -> list:
    from slamfront_plugins.loop_detectors.bow_evaluation import BowEvaluation

    # reports only when a detector emits BowStatistics
    return [BowEvaluation()] if "loop_detector" in kinds else []
