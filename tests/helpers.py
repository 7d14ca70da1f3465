"""Small builders shared by the tests."""

from __future__ import annotations

from typing import Any


def small_synthetic_recipe(**source_params: Any) -> dict[str, Any]:
    """A recipe dict for a quick synthetic run (few, small frames)."""
    params = {"frames_per_traversal": 40, "route_length_m": 80, "image_width": 64, "image_height": 48}
    params.update(source_params)
    return {
        "name": "small",
        "source": {"plugin": "synthetic", "params": params},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {}},
        "eval": {"plots": False},
    }
