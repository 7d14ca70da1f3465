"""Built-in place maps."""

from slamfront import hookimpl
from slamfront_plugins.place_maps.flat import FlatPlaceMap
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap


@hookimpl
def slamfront_place_maps() -> list[type]:
    return [HierarchicalPlaceMap, FlatPlaceMap]
