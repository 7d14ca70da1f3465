"""The ``hierarchical_sequence`` loop detector: three-level sequence matching (Rodrigues 2019 ch. 3).

Online, as in Alg. 1: query frames arrive one at a time and the ``hierarchical`` place
map groups them into places. When the rho-th place since the last query sequence is
complete (the first frame of the next place arrived), the last rho places form the
query sequence Q and one iteration runs:

1. level 1: the psi map places nearest to ``R(q_rho)`` (exact VP-tree search) give the
   candidate sequences;
2. level 2: the candidate nearest to Q place by place, checked for temporal
   consistency with the previous iteration; an inconsistent one waits for the next
   iteration, and one inconsistent with both is rebuilt from the previous processed
   sequence plus the rho places after it;
3. level 3: the chosen place sequence is expanded to frames (padded with neighbouring
   places when shorter than Q's frames), Q's frames are slid along it (template
   matching), the synthetic continuation of the previous match competes, and every
   query frame gets its aligned reference frame with confidence ``1 - v / max_distance``,
   v being the mean distance of the aligned pairs (eq. 3.14).

Answers therefore come out when Q completes, or one iteration later when its sequence
had to wait. Every query frame ends with a ``LoopResult``: a match and a confidence, or
``match = -1`` with the reason (map too small, no candidate, nothing to rebuild from,
featureless frame, traversal ended before its sequence was complete). Each level-3
decision is also logged as a ``SequenceDecision``.

Deviations from the letter of Rodrigues 2019, where it is ambiguous or inconsistent:
- the synthetic descriptor sequence (eq. 3.12) takes as many frames as Q-bar has, so
  eq. 3.13 compares sums of equal length; it is skipped when the map ends first;
- a rebuilt sequence is the last rho places of the previous processed sequence plus
  the rho places after it (it does not keep growing over consecutive rebuilds);
- featureless query frames (all-zero descriptors) get no answer and are left out of v;
- at the end of the traversal a sequence still waiting is treated as not validated by
  the next iteration (rebuilt); places left over after the last full Q get no answer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import Field

from slamfront import LoopDetector, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.messages import LoopResult, Message, PlaceAssignment
from slamfront_plugins.loop_detectors.hierarchical_levels import (
    Dispatch,
    FrameMatch,
    TemporalConsistency,
    candidate_sequences,
    match_frames,
    sequence_costs,
)
from slamfront_plugins.place_maps.hierarchical import HierarchicalPlaceMap


@dataclass(frozen=True, eq=False)
class SequenceDecision(Message):
    """One level-3 call of the hierarchical detector: which map sequence answered which query sequence, and why."""

    schema_name: ClassVar[str] = "slamfront.SequenceDecision"
    plain_fields: ClassVar[tuple[str, ...]] = ("candidate_costs",)
    iteration: int
    query_places: list[int]
    query_frames: np.ndarray
    """(n,) int64 frame indices of Q-bar."""
    candidates: np.ndarray
    """(K, 2) int64 level-1 candidate sequences (first, last map position), by level-2 cost."""
    candidate_costs: np.ndarray
    """(K,) float64 eq. 3.5 cost of each candidate."""
    branch: str
    """consistent, validated_by_next, rebuilt, unresolved, or a no-answer reason key."""
    first: int = -1
    last: int = -1
    template_offset: int = -1
    template_cost: float = float("nan")
    synthetic_cost: float = float("nan")
    used_synthetic: bool = False
    padded_places: int = 0
    confidence: float = float("nan")
    reason: str = ""


@dataclass
class _Iteration:
    """A query sequence between level 2 and level 3."""

    number: int
    places: list[int]
    frames: np.ndarray
    candidates: list[tuple[int, int]]
    costs: np.ndarray


class HierarchicalSequence(LoopDetector):
    """Three-level sequence-based loop closure detection over a hierarchical place map (Rodrigues 2019).

    Query sequences of ``rho`` places are searched in the map: level 1 finds ``psi``
    candidate place sequences with the VP-tree, level 2 keeps the best one that is
    temporally consistent (``alpha``), level 3 aligns the frames and gives each query
    frame a match and a confidence, or an explicit no-answer. Needs the
    ``hierarchical`` place map. Defaults: Rodrigues 2019 Table 4.1.
    """

    name = "hierarchical_sequence"
    requires = ("descriptor", "place_map")

    class Config(PluginConfig):
        rho: int = Field(5, ge=1, description="places per query sequence |Q| = |F| (Table 4.1)")
        psi: int = Field(10, ge=1, description="nearest neighbours searched at level 1 (Table 4.1)")
        alpha: int = Field(5, ge=1, description="temporal consistency: max |I(f_rho^{i-1}) - I(f_1^i)| (Table 4.1)")
        accept_confidence: float = Field(
            0.75, ge=0, le=1, description="operating point: matches at this confidence or more are accepted"
        )
        query_joins_map: bool = Field(
            False, description="query places join the map after their iteration (Rodrigues 2019 §4.4 keeps the map "
            "to the reference traversal; stream traversals always join)"
        )
        exclude_recent_places: int = Field(
            20, ge=0, description="stream traversals: the most recent map places are not loop candidates"
        )
        candidates: int = Field(10, ge=1, description="ranked candidate frames reported per query (recall@K)")

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._map: HierarchicalPlaceMap | None = None
        self._consistency = TemporalConsistency(self.config.rho, self.config.alpha)
        self._pending: list[int] = []  # closed query places not yet in a Q
        self._open_place: int | None = None
        self._iterations: dict[int, _Iteration] = {}
        self._n_iterations = 0
        self._last_matched: int | None = None  # map-frame position, for the synthetic sequence
        self._counts: dict[str, int] = {}
        self._query_frames = 0
        self._query_places = 0

    def check(self, stages: Mapping[str, Plugin]) -> None:
        if not isinstance(stages.get("place_map"), HierarchicalPlaceMap):
            found = stages["place_map"].name if "place_map" in stages else "none"
            raise PluginError(f"needs the 'hierarchical' place map (found {found!r})")

    # --- the stream -----------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        self._map = inputs.stages["place_map"]  # type: ignore[assignment]
        frame = inputs.frame
        if frame.traversal == "reference":
            return []
        assignment: PlaceAssignment = inputs.one("place_map", PlaceAssignment)
        self._query_frames += 1
        out: list[Message] = []
        if assignment.new_place:
            self._query_places += 1
            if self._open_place is not None:
                out += self._close(self._open_place, frame.traversal)
            self._open_place = assignment.place
        return out

    def finish(self) -> Sequence[Message]:
        out: list[Message] = []
        if self._map is None:
            return out
        if self._open_place is not None:
            out += self._close(self._open_place, self._map.places[self._open_place].traversal)
            self._open_place = None
        for dispatch in self._consistency.finish(self._map.n_map_places):
            out += self._level3(dispatch)
        for place in self._pending:
            out += self._no_answer(self._frames_of([place]), "traversal ended before its query sequence was complete")
        self._pending = []
        return out

    def _close(self, place: int, traversal: str) -> list[Message]:
        """A query place is complete; run an iteration when it completes a Q."""
        self._pending.append(place)
        if len(self._pending) < self.config.rho:
            return []
        places, self._pending = self._pending, []
        out = self._iteration(places)
        if traversal == "stream" or self.config.query_joins_map:
            for p in places:  # Alg. 1 line 14: Q joins the map after its iteration
                self._map.commit(p)  # type: ignore[union-attr]
        return out

    # --- levels 1 and 2 -------------------------------------------------------------------

    def _iteration(self, places: list[int]) -> list[Message]:
        c = self.config
        pm = self._map
        assert pm is not None
        self._n_iterations += 1
        number = self._n_iterations
        frames = self._frames_of(places)
        if pm.n_map_places <= c.rho:
            self._count("map_too_small")
            out = self._dispatch_all(self._consistency.step(number, None, pm.n_map_places))
            return out + self._no_answer(frames, f"the map has {pm.n_map_places} places, not more than rho={c.rho}")
        hi = pm.n_map_places - 1
        if pm.places[places[-1]].traversal == "stream":
            hi -= c.exclude_recent_places
        hits, _ = pm.nearest(pm.representative(places[-1]), c.psi, lo=c.rho - 1, hi=hi) if hi >= c.rho - 1 else ([], [])
        candidates = candidate_sequences(np.asarray(hits), c.rho)
        self._counts["searches"] = self._counts.get("searches", 0) + 1
        if not candidates:
            self._count("no_candidate")
            out = self._dispatch_all(self._consistency.step(number, None, pm.n_map_places))
            return out + self._no_answer(frames, "level 1 found no candidate sequence")
        query_reps = np.stack([pm.representative(p) for p in places])
        candidate_reps = np.stack([pm.map_representatives(range(first, last + 1)) for first, last in candidates])
        costs = sequence_costs(query_reps, candidate_reps, pm.metric)
        order = np.argsort(costs, kind="stable")
        ranked = [candidates[k] for k in order]
        self._iterations[number] = _Iteration(number, places, frames, ranked, costs[order])
        return self._dispatch_all(self._consistency.step(number, ranked[0], pm.n_map_places))

    def _dispatch_all(self, dispatches: list[Dispatch]) -> list[Message]:
        out: list[Message] = []
        for dispatch in dispatches:
            out += self._level3(dispatch)
        return out

    # --- level 3 --------------------------------------------------------------------------

    def _level3(self, dispatch: Dispatch) -> list[Message]:
        pm = self._map
        assert pm is not None
        iteration = self._iterations.pop(dispatch.iteration)
        self._count(dispatch.branch)
        decision = dict(
            iteration=dispatch.iteration, query_places=iteration.places, query_frames=iteration.frames,
            candidates=np.asarray(iteration.candidates, dtype=np.int64).reshape(-1, 2),
            candidate_costs=np.asarray(iteration.costs, dtype=np.float64), branch=dispatch.branch,
        )
        if dispatch.sequence is None:
            reason = "inconsistent with both neighbouring iterations and no earlier sequence to rebuild from"
            return [SequenceDecision(**decision, reason=reason), *self._no_answer(iteration.frames, reason)]
        query = pm.vectors(iteration.frames)
        informative = np.abs(query).sum(axis=1) > 0
        offsets = pm.place_offsets()
        match = match_frames(
            query, informative, dispatch.sequence, offsets,
            lambda start, stop: pm.vectors(pm.map_frames(start, stop)), pm.metric,
            self._last_matched, dispatch.synthetic,
        )
        first, last = dispatch.sequence
        if match.reason:
            self._count("no_padding")
            return [SequenceDecision(**decision, first=first, last=last, reason=match.reason),
                    *self._no_answer(iteration.frames, match.reason)]
        if match.used_synthetic:
            self._count("synthetic_frames")
        self._last_matched = int(match.aligned[-1])
        confidence = float(pm.similarity(match.mean_distance)) if np.isfinite(match.mean_distance) else 0.0
        results = self._answers(iteration, match, informative, confidence)
        record = SequenceDecision(
            **decision, first=first, last=last, template_offset=match.template_offset,
            template_cost=match.template_cost, synthetic_cost=match.synthetic_cost,
            used_synthetic=match.used_synthetic, padded_places=match.padded_places, confidence=confidence,
        )
        return [record, *results]

    def _answers(
        self, iteration: _Iteration, match: FrameMatch, informative: np.ndarray, confidence: float
    ) -> list[LoopResult]:
        pm = self._map
        assert pm is not None
        matched = pm.map_frames(0, pm.n_map_frames)[match.aligned]
        alternatives = self._alternatives(iteration, len(iteration.frames))
        out = []
        for k, frame in enumerate(iteration.frames.tolist()):
            if not informative[k]:
                self._count("featureless")
                out.append(LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                                      reason="featureless query frame (no edges to describe)"))
                continue
            ranked = [int(matched[k]), *(int(a) for a in alternatives[k] if a != matched[k])]
            out.append(LoopResult(
                frame=frame, match=int(matched[k]), confidence=confidence,
                accepted=confidence >= self.config.accept_confidence,
                candidates=np.asarray(ranked[: self.config.candidates], dtype=np.int64),
            ))
        return out

    def _alternatives(self, iteration: _Iteration, n: int) -> list[list[int]]:
        """For recall@K: per query frame, the frame at the same relative position in each
        other level-1 candidate sequence, in level-2 order (a ranking, not a detection)."""
        pm = self._map
        assert pm is not None
        columns = []
        for first, last in iteration.candidates[1:]:
            start, stop = pm.map_frame_range(first, last)
            positions = start + np.minimum((np.arange(n) * (stop - start)) // max(n, 1), stop - start - 1)
            columns.append(pm.map_frames(0, pm.n_map_frames)[positions])
        return [[int(col[k]) for col in columns] for k in range(n)]

    def _no_answer(self, frames: np.ndarray, reason: str) -> list[LoopResult]:
        self._counts["no_answer_frames"] = self._counts.get("no_answer_frames", 0) + len(frames)
        return [LoopResult(frame=int(f), match=-1, confidence=0.0, accepted=False, reason=reason) for f in frames]

    def _frames_of(self, places: list[int]) -> np.ndarray:
        pm = self._map
        assert pm is not None
        return np.asarray([f for p in places for f in pm.places[p].frames], dtype=np.int64)

    def _count(self, key: str) -> None:
        self._counts[key] = self._counts.get(key, 0) + 1

    def statistics(self) -> dict[str, float | int]:
        stats: dict[str, float | int] = {
            "n_searches": self._counts.get("searches", 0),
            "n_query_sequences": self._n_iterations,
            "n_query_frames": self._query_frames,
        }
        for key in ("consistent", "validated_by_next", "rebuilt", "unresolved", "synthetic_frames",
                    "map_too_small", "no_candidate", "no_padding", "featureless", "no_answer_frames"):
            stats[f"n_{key}"] = self._counts.get(key, 0)
        return stats
