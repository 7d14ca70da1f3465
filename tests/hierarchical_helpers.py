"""Feeding hand-made descriptors through the place map and the hierarchical detector, without rendering."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slamfront import Frame, LoopDetector, PlaceMap, StageInputs
from slamfront.messages import Features, Message


def route_descriptors(n_places: int, frames_per_place: int, dim: int = 32, seed: int = 0) -> np.ndarray:
    """(n_places * frames_per_place, dim) unit-L1 descriptors of a route: frames of a place
    are near-identical, places are unrelated."""
    rng = np.random.default_rng(seed)
    bases = rng.random((n_places, dim)) ** 4
    frames = np.repeat(bases, frames_per_place, axis=0) + rng.random((n_places * frames_per_place, dim)) * 0.002
    return (frames / frames.sum(axis=1, keepdims=True)).astype(np.float32)


def noisy(vectors: np.ndarray, amount: float, seed: int = 1) -> np.ndarray:
    """The same descriptors seen again under a change (multiplicative noise), renormalised."""
    rng = np.random.default_rng(seed)
    changed = vectors * (1 + amount * rng.standard_normal(vectors.shape))
    changed = np.clip(changed, 0, None)
    return (changed / changed.sum(axis=1, keepdims=True)).astype(np.float32)


def dusk_like_route(amount: float) -> tuple[np.ndarray, list[str]]:
    """A route of 150 places (2 frames each) that share much of their look (less contrast than
    :func:`route_descriptors`), seen again under a strong change (``amount``): every query answer,
    right or wrong, is less confident than the reference's answers to itself, as at dusk.
    Returns the reference's then the query's descriptors and their traversals (300 of each)."""
    rng = np.random.default_rng(0)
    frames = np.repeat(rng.random((150, 32)), 2, axis=0) + rng.random((300, 32)) * 0.002
    reference = (frames / frames.sum(axis=1, keepdims=True)).astype(np.float32)
    query = noisy(reference, amount, seed=4)
    return np.concatenate([reference, query]), ["reference"] * len(reference) + ["query"] * len(query)


def run_stages(
    vectors: np.ndarray,
    traversals: Sequence[str],
    place_map: PlaceMap,
    detector: LoopDetector,
    on_output: list[tuple[int, list[Message]]] | None = None,
) -> list[Message]:
    """Run frames through place map and detector as the runtime does; returns every detector output.

    :param on_output: when given, receives ``(frame index, outputs)`` for each frame (finish: -1).
    """
    outputs: list[Message] = []
    for index, (vector, traversal) in enumerate(zip(vectors, traversals)):
        frame = Frame(index=index, timestamp=float(index), image=np.zeros((2, 2), np.uint8), traversal=traversal)  # type: ignore[arg-type]
        inputs = StageInputs(frame=frame, outputs={"descriptor": [Features(frame=index, vector=vector, metric="l1")]})
        inputs.outputs["place_map"] = list(place_map.process(inputs))
        inputs.stages = {"place_map": place_map}
        produced = list(detector.process(inputs))
        outputs += produced
        if on_output is not None:
            on_output.append((index, produced))
    produced = list(detector.finish())
    if on_output is not None:
        on_output.append((-1, produced))
    return outputs + produced
