"""The bag-of-words loop detector's own log message, declared through ``slamfront_message_types``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from slamfront.messages import Message


@dataclass(frozen=True, eq=False)
class BowStatistics(Message):
    """A bag-of-words loop detector's state after one frame (vocabulary, memory, filter, time).

    Counts refer to the state after the frame was processed. Float fields are NaN
    where they do not apply (no features; no other rule tracked).
    """

    schema_name: ClassVar[str] = "slamfront.BowStatistics"
    volatile_fields: ClassVar[tuple[str, ...]] = ("processing_seconds",)
    frame: int
    n_features: int
    new_words: int
    vocabulary_size: int
    """Words kept so far, in working or long-term memory (Wang et al. 2017, fig. 4)."""
    active_words: int
    """Words the nearest-word search scans (those of STM and WM places)."""
    quantisation_error: float
    """Mean distance of the frame's features to their words (Wang et al. 2017, fig. 6), in the
    vocabulary's unit: squared L2 (float descriptors) or bits."""
    by_ratio_test: int = -1
    """Features the ratio test ND / NND decided (the rest: ND > T_ND2 or ND < T_ND1); -1: none quantised."""
    by_nd_high: int = -1
    """Features that became words because ND > T_ND2, without the ratio test (greedy rule)."""
    update_rule: str = "greedy"
    other_rule: str = ""
    """The other update rule, when the detector also tracks its vocabulary for comparison."""
    other_vocabulary_size: int = -1
    other_quantisation_error: float = float("nan")
    place: int = -1
    """The place this frame created or was merged into; -1 for none (no features, a query)."""
    merged: bool = False
    """The frame was more similar than T_sim to the previous one and merged into its place."""
    stm_size: int = 0
    wm_size: int = 0
    """Places in working memory after this frame (Wang et al. 2017, fig. 9a)."""
    ltm_size: int = 0
    transferred: int = 0
    retrieved: int = 0
    no_loop_posterior: float = float("nan")
    max_loop_posterior: float = float("nan")
    """The largest p(S_t = i) (Wang et al. 2017, fig. 7)."""
    loop_threshold: float = float("nan")
    """T_loop: a loop is accepted when ``no_loop_posterior`` is below it."""
    processing_seconds: float = 0.0
    """This frame's detector time (Wang et al. 2017, fig. 9b)."""
    searched_words: int = 0
    """Words the nearest-word search scanned for this frame (the time grows with them)."""
    searched_places: int = 0
    """Places in working memory when the frame was searched (or would have been)."""
    modelled_seconds: float = float("nan")
    """The deterministic time model's seconds for this frame, when the budget is compared with it."""
    time_budget_seconds: float = 0.0
