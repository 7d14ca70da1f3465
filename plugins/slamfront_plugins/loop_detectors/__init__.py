"""Built-in loop detectors."""

from slamfront import hookimpl
from slamfront_plugins.loop_detectors.hierarchical_sequence import HierarchicalSequence
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour


@hookimpl
def slamfront_loop_detectors() -> list[type]:
    return [NearestNeighbour, HierarchicalSequence]
