"""Built-in loop detectors."""

from slamfront import hookimpl
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes
from slamfront_plugins.loop_detectors.hierarchical_faithful import HierarchicalFaithful
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from slamfront_plugins.loop_detectors.seqslam import SeqSlam, SeqSlamFast


@hookimpl
def slamfront_loop_detectors() -> list[type]:
    return [NearestNeighbour, HierarchicalSequence, HierarchicalFaithful, SeqSlam, SeqSlamFast, BowBayes]
