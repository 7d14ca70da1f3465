"""Built-in place maps and their own messages."""

from slamfront import hookimpl
from slamfront_plugins.place_maps.flat import FlatPlaceMap
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap


@hookimpl
def slamfront_place_maps() -> list[type]:
    return [HierarchicalPlaceMap, FlatPlaceMap]


@hookimpl
def slamfront_message_types() -> list[type]:
    from slamfront_plugins.place_maps.hierarchical import PlaceThreshold

    return [PlaceThreshold]
