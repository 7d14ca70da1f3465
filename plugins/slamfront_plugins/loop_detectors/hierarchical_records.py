"""What the frame-level hierarchical detector (:mod:`.hierarchical_sequence`) logs of each
answered query sequence, and what it keeps of a sequence while it waits to be answered."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from slamfront.messages import Message
from slamfront_plugins.loop_detectors.hierarchical_frames import Trajectory


@dataclass(frozen=True, eq=False)
class SequenceDecision(Message):
    """One answered query sequence of the frame-level hierarchical detector: the trajectory that answered it, and why."""

    schema_name: ClassVar[str] = "slamfront.SequenceDecision"
    plain_fields: ClassVar[tuple[str, ...]] = ("candidate_costs",)
    iteration: int
    query_places: list[int]
    query_frames: np.ndarray
    """(n,) int64 frame indices of Q-bar."""
    candidates: np.ndarray
    """(K, 2) int64, by level-2 cost: (map position of the level-1 place, -1 for the track;
    map-frame position its best trajectory pairs with Q's last frame)."""
    candidate_costs: np.ndarray
    """(K,) float64 level-2 cost of each candidate: mean distance along its best trajectory."""
    branch: str
    """consistent, validated_by_next, isolated, or inconsistent (``isolate: false``)."""
    first: int = -1
    """Map-frame position paired with Q's first frame."""
    last: int = -1
    """Map-frame position paired with Q's last frame."""
    cost: float = float("nan")
    """Level-2 cost of the best candidate."""
    track: bool = False
    """The best candidate was the track (the last answer, continued)."""
    speed: float = float("nan")
    """Speed of the line answered along (map frames per query frame; negative: the query runs
    the map backwards)."""
    direction: str = ""
    """forward or reverse: the direction the answered line runs through the map."""
    confidence: float = float("nan")
    line_uniqueness: float = float("nan")
    """How much better the answered line fits than itself moved by ``anchor_slack + 1 ..
    uniqueness_window`` frames (the uniqueness confidence is at most this; NaN: not checked)."""


@dataclass
class Answer:
    """A query sequence compared frame by frame, waiting to be answered."""

    number: int
    places: list[int]
    frames: np.ndarray
    positions: np.ndarray
    """(n,) query positions of the frames."""
    trajectories: list[tuple[Trajectory, int]]
    """(trajectory, level-1 map place or -1 for the track), best first."""
    confidence: float
    """Its own: the uniqueness of the best trajectory (or 1 - v/2 with ``confidence: distance``)."""
    evidence: float
    """The confidence accumulated along the consistent run it ends."""
    consistent: bool
    """Consistent with the previous iteration's answer."""
    n_map: int
    """Map-frame positions 0..n_map-1 could be paired when it was compared."""
    map_informative: np.ndarray
    """(n_map,) bool, the map frames that were not featureless then."""
    window_start: int
    """The first query position its trajectories were compared over."""
