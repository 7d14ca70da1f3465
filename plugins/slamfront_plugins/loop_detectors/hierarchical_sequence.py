"""The ``hierarchical_sequence`` loop detector: three-level sequence matching (Rodrigues 2019 ch. 3).

Online, as in Alg. 1: query frames arrive one at a time and the ``hierarchical`` place
map groups them into places. When the rho-th place since the last query sequence is
complete (the first frame of the next place arrived), the last rho places form the
query sequence Q and one iteration runs. Level 1 is the same in both modes: the psi map
places nearest to ``R(q_rho)`` (exact search) give the candidates. Two modes differ after it:

``mode: faithful`` (Rodrigues 2019 to the letter, :mod:`.hierarchical_levels`):

2. level 2: the candidate nearest to Q place by place (eq. 3.5), checked for temporal
   consistency with the previous iteration; an inconsistent one waits for the next
   iteration, and one inconsistent with both is rebuilt from the previous processed
   sequence plus the rho places after it;
3. level 3: the chosen place sequence is expanded to frames (padded with neighbouring
   places when shorter than Q's frames), Q's frames are slid along it (template
   matching), the synthetic continuation of the previous match competes, and every
   query frame gets its aligned reference frame with confidence ``1 - v / max_distance``,
   v being the mean distance of the aligned pairs (eq. 3.14).

``mode: frames`` (the default, :mod:`.hierarchical_frames`):

2. level 2 compares every candidate frame by frame: straight trajectories through the
   map frames at speeds ``vmin..vmax`` over the last ``sequence_frames`` query frames,
   anchored where level 1 paired the query place with a map place. The last answer,
   continued, is one more candidate (the *track*); it replaces the faithful mode's
   rebuilt sequence and synthetic continuation, but is re-aligned to the descriptors
   and must beat level 1's candidates at every iteration, so it cannot drift away
   from the data. Temporal consistency (alpha, in frames) works as in Alg. 3: an answer
   inconsistent with the previous one waits for the next iteration; validated by it,
   it is answered, otherwise it is answered as *isolated* with confidence 0;
3. level 3: each frame of Q is paired along the best trajectory; when the next sequence
   goes on elsewhere, Q's newest frames that fit its trajectory better get no answer
   (``leave_line``: the route jumped in the map). The confidence is, for paired
   traversals, the best trajectory's uniqueness among the candidates,
   ``1 - cost / second`` (second: the best candidate ending more than
   ``uniqueness_window`` frames away), as SeqSLAM's, and at most the answered line's
   uniqueness against itself moved by a few frames (``line_check``: look-alike frames);
   in a stream, where most queries have no true match, eq. 3.14's
   ``1 - v / max_distance`` (``confidence: auto``).

Answers come out when Q completes, or one iteration later when its sequence had to
wait. Every query frame ends with a ``LoopResult``: a match and a confidence, or
``match = -1`` with the reason (map too small, no candidate, nothing to rebuild from,
featureless frame, traversal ended before its sequence was complete). Each level-3
decision is also logged as a ``SequenceDecision``. The descriptor distances the
detector computes (level-1 search and sequence comparisons) are counted
(``n_distances``).

Deviations from the letter of Rodrigues 2019 in the faithful mode, where it is ambiguous
or inconsistent:
- the synthetic descriptor sequence (eq. 3.12) takes as many frames as Q-bar has, so
  eq. 3.13 compares sums of equal length; it is skipped when the map ends first;
- a rebuilt sequence is the last rho places of the previous processed sequence plus
  the rho places after it (it does not keep growing over consecutive rebuilds);
- featureless query frames (all-zero descriptors) get no answer and are left out of v;
- at the end of the traversal a sequence still waiting is treated as not validated by
  the next iteration (rebuilt); places left over after the last full Q get no answer.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import LoopDetector, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.core.distances import rowwise
from slamfront.messages import LoopResult, Message, PlaceAssignment
from slamfront_plugins.loop_detectors.hierarchical_frames import (
    PairDistances,
    Trajectory,
    best_trajectory,
    line_uniqueness,
    speeds,
    uniqueness,
)
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
    """(K, 2) int64, by level-2 cost. Faithful: level-1 candidate sequences (first, last map
    position). Frames: (map position of the level-1 place, -1 for the track; map-frame
    position its best trajectory pairs with Q's last frame)."""
    candidate_costs: np.ndarray
    """(K,) float64 level-2 cost of each candidate (eq. 3.5; frames: mean trajectory distance)."""
    branch: str
    """consistent, validated_by_next, rebuilt, unresolved, isolated (frames), or a no-answer reason key."""
    first: int = -1
    """Faithful: first map place of F*. Frames: map-frame position paired with Q's first frame."""
    last: int = -1
    """Faithful: last map place of F*. Frames: map-frame position paired with Q's last frame."""
    template_offset: int = -1
    template_cost: float = float("nan")
    synthetic_cost: float = float("nan")
    used_synthetic: bool = False
    """Faithful: the synthetic continuation won (eq. 3.13). Frames: the track won."""
    padded_places: int = 0
    confidence: float = float("nan")
    reason: str = ""
    speed: float = float("nan")
    """Frames: the speed of the chosen trajectory (map frames per query frame)."""
    line_uniqueness: float = float("nan")
    """Frames, uniqueness confidence: how much better the answered line fits than itself moved
    by ``anchor_slack + 1 .. uniqueness_window`` frames (the confidence is at most this)."""
    left_line_at: int = -1
    """Frames: the first query frame answered no more because the route left the line there (-1: none)."""


DISTANCE_ACCEPT = 0.75
"""Default operating point of eq. 3.14's confidence ``1 - v/2``."""
UNIQUENESS_ACCEPT = 0.04
"""Default operating point of the uniqueness confidence ``1 - best/second`` (with the line
check): on the held-out data (Nordland frames 2900-3575, also with a 150-frame block moved
or replaced at frames 200 or 350 of it, and synthetic world seeds 100-102) every answer
above 0.032 was correct; rounded up for a margin."""


@dataclass
class _Iteration:
    """A query sequence between level 2 and level 3 (faithful mode)."""

    number: int
    places: list[int]
    frames: np.ndarray
    candidates: list[tuple[int, int]]
    costs: np.ndarray


@dataclass
class _FrameAnswer:
    """A query sequence compared frame by frame, waiting to be answered (frames mode)."""

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


class HierarchicalSequence(LoopDetector):
    """Three-level sequence-based loop closure detection over a hierarchical place map (Rodrigues 2019).

    Query sequences of ``rho`` places are searched in the map: level 1 finds ``psi``
    candidate places with the VP-tree, level 2 keeps the best temporally consistent
    candidate (``alpha``), level 3 aligns the frames and gives each query frame a match
    and a confidence, or an explicit no-answer. ``mode: frames`` (default) compares the
    candidates frame by frame as trajectories and continues the last answer as a
    candidate; ``mode: faithful`` is Rodrigues 2019 to the letter (place-by-place level 2,
    rebuilt sequences, synthetic continuation). Needs the ``hierarchical`` place map.
    Defaults of rho, psi, alpha: Rodrigues 2019 Table 4.1.
    """

    name = "hierarchical_sequence"
    requires = ("descriptor", "place_map")

    class Config(PluginConfig):
        mode: Literal["frames", "faithful"] = Field(
            "frames", description="frames: level 2 compares candidates frame by frame, the last answer is "
            "continued as a candidate; faithful: Rodrigues 2019's place-by-place level 2, rebuild and synthetic "
            "continuation"
        )
        rho: int = Field(5, ge=1, description="places per query sequence |Q| = |F| (Table 4.1)")
        psi: int = Field(10, ge=1, description="nearest neighbours searched at level 1 (Table 4.1)")
        alpha: int = Field(
            5, ge=1, description="temporal consistency: max |I(f_rho^{i-1}) - I(f_1^i)| in places (Table 4.1); "
            "frames mode: max distance in map frames between an answer and the previous one continued"
        )
        accept_confidence: float | None = Field(
            None, ge=0, le=1, description="operating point: matches at this confidence or more are accepted; "
            "unset: 0.75 for eq. 3.14's distance confidence, 0.04 for uniqueness (chosen on held-out data)"
        )
        query_joins_map: bool = Field(
            False, description="query places join the map after their iteration (Rodrigues 2019 §4.4 keeps the map "
            "to the reference traversal; stream traversals always join)"
        )
        exclude_recent_places: int = Field(
            20, ge=0, description="stream traversals: the most recent map places are not loop candidates"
        )
        candidates: int = Field(10, ge=1, description="ranked candidate frames reported per query (recall@K)")
        sequence_frames: int = Field(
            40, ge=2, description="frames mode: query frames compared per candidate (at least Q's frames)"
        )
        vmin: float = Field(0.8, gt=0, description="frames mode: slowest trajectory, map frames per query frame")
        vmax: float = Field(1.25, gt=0, description="frames mode: fastest trajectory")
        anchor_slack: int = Field(
            2, ge=0, description="frames mode: map frames either side of an anchor tried (a place spans frames)"
        )
        uniqueness_window: int = Field(
            10, ge=0, description="frames mode: candidates ending within this many map frames of the best one do "
            "not count as the second best"
        )
        refine: int = Field(
            3, ge=0, description="frames mode: when > 0, only the best `refine` level-1 candidates at speed 1 "
            "over the last screen_frames (and the track) get the full comparison; 0: all of them"
        )
        screen_frames: int = Field(6, ge=1, description="frames mode: query frames of the screening (refine > 0)")
        track: bool = Field(True, description="frames mode: the last answer, continued, is a candidate too")
        confidence: Literal["auto", "uniqueness", "distance"] = Field(
            "auto", description="frames mode: 1 - best / second best far candidate (as SeqSLAM), or "
            "1 - v / max_distance of the chosen pairs (eq. 3.14, the faithful mode's); auto: uniqueness for "
            "paired traversals, distance for a stream (whose queries mostly have no true match)"
        )
        evidence_iterations: int = Field(
            3, ge=1, description="frames mode: an answer's confidence is the mean over the last this many "
            "iterations of the consistent run it continues (1: its own iteration only)"
        )
        realign: bool = Field(
            True, description="frames mode, level 3: Q's own frames are slid along the chosen trajectory and at "
            "speed 1 (eq. 3.10), -anchor_slack..anchor_slack map frames, and answered where they fit best"
        )
        isolate: bool = Field(
            True, description="frames mode: an answer inconsistent with the previous one waits for the next; "
            "consistent with neither, it keeps confidence 0 (False: every answer at once, with its confidence)"
        )
        line_check: bool = Field(
            True, description="frames mode, uniqueness confidence (paired traversals): the confidence is at most the answered line's "
            "uniqueness against the same line moved by anchor_slack + 1 .. uniqueness_window map frames, over Q "
            "and the window that chose the line (a stretch of look-alike frames cannot say which is right)"
        )
        leave_line: bool = Field(
            True, description="frames mode: when the next sequence goes on elsewhere, Q's newest frames that fit its "
            "trajectory better than Q's own line get no answer (the route left the line there)"
        )

        @model_validator(mode="after")
        def _speeds(self) -> HierarchicalSequence.Config:
            if self.vmin > self.vmax:
                raise ValueError("vmin must not exceed vmax")
            return self

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        c = self.config
        self._map: HierarchicalPlaceMap | None = None
        self._consistency = TemporalConsistency(c.rho, c.alpha)
        self._awaiting: deque[int] = deque()  # query frames whose place is not known yet
        self._pending: list[int] = []  # closed query places not yet in a Q
        self._open_place: int | None = None
        self._iterations: dict[int, _Iteration] = {}
        self._n_iterations = 0
        self._last_matched: int | None = None  # map-frame position, for the synthetic sequence
        self._counts: dict[str, int] = {}
        self._query_frames = 0
        self._query_places = 0
        # frames mode
        self._order: list[int] = []  # query frames by query position
        self._position: dict[int, int] = {}
        self._informative: list[bool] = []
        self._speeds = speeds(c.vmin, c.vmax, c.sequence_frames)
        self._pairs = PairDistances(self._pair_distances, keep=4 * c.sequence_frames)
        self._track: tuple[Trajectory, int] | None = None  # the last answer and the query position it ended at
        self._waiting: _FrameAnswer | None = None  # the last sequence, answered when the next one is compared
        self._run: list[float] = []  # confidences of the current run of consistent sequences
        self._sequence_distances = 0
        self._confidence_kind: str | None = None if c.confidence == "auto" else c.confidence
        self._accept = c.accept_confidence if c.accept_confidence is not None else (
            UNIQUENESS_ACCEPT if c.mode == "frames" and c.confidence == "uniqueness" else DISTANCE_ACCEPT)

    def check(self, stages: Mapping[str, Plugin]) -> None:
        if not isinstance(stages.get("place_map"), HierarchicalPlaceMap):
            found = stages["place_map"].name if "place_map" in stages else "none"
            raise PluginError(f"needs the 'hierarchical' place map (found {found!r})")

    # --- the stream -----------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        self._map = inputs.stages["place_map"]  # type: ignore[assignment]
        if inputs.frame.traversal != "reference":
            self._awaiting.append(inputs.frame.index)
        out: list[Message] = []
        # the place map may place several frames at once (those it held while choosing nu)
        for assignment in inputs.outputs.get("place_map", ()):
            if isinstance(assignment, PlaceAssignment) and self._awaiting and assignment.frame == self._awaiting[0]:
                self._awaiting.popleft()
                out += self._placed(assignment.frame, assignment.place, assignment.new_place)
        return out

    def finish(self) -> Sequence[Message]:
        out: list[Message] = []
        pm = self._map
        if pm is None:
            return out
        while self._awaiting:  # placed by the place map's own finish (a run shorter than its calibration)
            frame = self._awaiting.popleft()
            place = pm.place_of(frame)
            out += self._placed(frame, place, pm.places[place].frames[0] == frame)
        if self._open_place is not None:
            out += self._close(self._open_place, pm.places[self._open_place].traversal)
            self._open_place = None
        if self.config.mode == "faithful":
            for dispatch in self._consistency.finish(pm.n_map_places):
                out += self._level3(dispatch)
        else:
            out += self._settle(None)
        for place in self._pending:
            out += self._no_answer(self._frames_of([place]), "traversal ended before its query sequence was complete")
        self._pending = []
        return out

    def _placed(self, frame: int, place: int, new_place: bool) -> list[Message]:
        pm = self._map
        assert pm is not None
        self._query_frames += 1
        self._position[frame] = len(self._order)
        self._order.append(frame)
        self._informative.append(bool(pm.informative([frame])[0]))
        out: list[Message] = []
        if new_place:
            self._query_places += 1
            if self._open_place is not None:
                out += self._close(self._open_place, pm.places[place].traversal)
            self._open_place = place
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

    # --- level 1 --------------------------------------------------------------------------

    def _iteration(self, places: list[int]) -> list[Message]:
        c = self.config
        pm = self._map
        assert pm is not None
        self._n_iterations += 1
        number = self._n_iterations
        frames = self._frames_of(places)
        usable = pm.n_map_places - (c.exclude_recent_places if pm.places[places[-1]].traversal == "stream" else 0)
        smallest = c.rho if c.mode == "faithful" else 0
        if usable <= smallest:
            self._count("map_too_small")
            out = self._flush(number, pm.n_map_places)
            what = f"not more than rho={c.rho}" if c.mode == "faithful" else "none to search"
            return out + self._no_answer(frames, f"the map has {max(usable, 0)} places, {what}")
        lo = c.rho - 1 if c.mode == "faithful" else 0
        hits, _ = pm.nearest(pm.representative(places[-1]), c.psi, lo=lo, hi=usable - 1) if usable - 1 >= lo else ([], [])
        self._count("searches")
        if c.mode == "frames":
            return self._frame_iteration(number, places, frames, np.asarray(hits, dtype=np.int64), usable)
        candidates = candidate_sequences(np.asarray(hits), c.rho)
        if not candidates:
            self._count("no_candidate")
            out = self._flush(number, pm.n_map_places)
            return out + self._no_answer(frames, "level 1 found no candidate sequence")
        query_reps = np.stack([pm.representative(p) for p in places])
        candidate_reps = np.stack([pm.map_representatives(range(first, last + 1)) for first, last in candidates])
        costs = sequence_costs(query_reps, candidate_reps, pm.metric)
        self._sequence_distances += len(candidates) * c.rho
        order = np.argsort(costs, kind="stable")
        ranked = [candidates[k] for k in order]
        self._iterations[number] = _Iteration(number, places, frames, ranked, costs[order])
        return self._dispatch_all(self._consistency.step(number, ranked[0], pm.n_map_places))

    def _flush(self, number: int, n_map_places: int) -> list[Message]:
        """An iteration without candidates: what waited can no longer be validated by it."""
        if self.config.mode == "faithful":
            return self._dispatch_all(self._consistency.step(number, None, n_map_places))
        self._run = []
        return self._settle(None)

    # --- frames mode: levels 2 and 3 --------------------------------------------------------

    def _pair_distances(self, positions: np.ndarray, map_positions: np.ndarray) -> np.ndarray:
        pm = self._map
        assert pm is not None
        frames = [self._order[p] for p in positions.tolist()]
        return rowwise(pm.vectors(frames), pm.vectors(pm.map_frames_at(map_positions)), pm.metric)  # type: ignore[arg-type]

    def _frame_iteration(
        self, number: int, places: list[int], frames: np.ndarray, hits: np.ndarray, usable: int
    ) -> list[Message]:
        c = self.config
        pm = self._map
        assert pm is not None
        n_map = pm.map_frame_range(0, usable - 1)[1]
        map_informative = pm.informative(pm.map_frames_at(np.arange(n_map)))
        positions = np.asarray([self._position[f] for f in frames], dtype=np.int64)
        end = int(positions[-1])
        start = max(0, end - max(c.sequence_frames, len(frames)) + 1)
        blind = self._blind_stretch(start, end)
        rows = self._informative_rows(range(max(start, blind + 1), end + 1))
        anchor = self._position[pm.places[places[-1]].frames[0]]
        anchors = [(anchor, pm.map_frame_range(int(h), int(h))[0], int(h)) for h in hits]
        if self._track is not None and c.track:
            track, at = self._track
            anchors.append((at, int(track.at(at)), -1))
        trajectories = self._compare(anchors, rows, n_map, map_informative)
        if not trajectories:
            self._count("no_candidate")
            return self._flush(number, pm.n_map_places) + self._no_answer(
                frames, "no candidate sequence fits in the map" if anchors else "level 1 found no candidate"
            )
        ends = np.asarray([int(t.at(end)) for t, _ in trajectories])
        costs = np.asarray([t.cost for t, _ in trajectories])
        best = trajectories[0][0]
        confidence = uniqueness(costs, ends, 0, c.uniqueness_window) if self._kind(places) == "uniqueness" \
            else float(pm.similarity(best.cost))
        consistent = self._track is not None and abs(int(best.at(end)) - int(self._track[0].at(end))) <= c.alpha
        self._track = (best, end)
        # evidence accumulates along a run of consistent sequences; it restarts with an
        # inconsistent one, or after a featureless stretch (earlier frames do not vouch for it)
        self._run = [*self._run, confidence] if consistent and blind < start else [confidence]
        record = _FrameAnswer(number, places, frames, positions, trajectories, confidence,
                              float(np.mean(self._run[-c.evidence_iterations:])), consistent, n_map, map_informative,
                              int(rows[0]) if len(rows) else start)
        if not c.isolate:
            return self._frame_answers(record, "consistent" if consistent else "inconsistent", [best], record.confidence,
                                       (min(record.window_start, int(positions[0])), end))
        return self._settle(record)

    def _kind(self, places: list[int]) -> str:
        """The frames mode's confidence, ``auto`` resolved at the first sequence: in a stream
        most queries come before any revisit and have no true match, so only how similar
        the answer is (eq. 3.14) can tell a revisit from a look-alike; uniqueness, which
        ranks an answer against the other candidates, cannot (a repetitive street makes
        true revisits look no more unique than look-alikes). Paired traversals: uniqueness."""
        if self._confidence_kind is None:
            stream = self._map is not None and self._map.places[places[-1]].traversal == "stream"
            self._confidence_kind = "distance" if stream else "uniqueness"
            if self.config.accept_confidence is None:
                self._accept = DISTANCE_ACCEPT if stream else UNIQUENESS_ACCEPT
        return self._confidence_kind

    def _settle(self, record: _FrameAnswer | None) -> list[Message]:
        """Answer the waiting sequence now that the next one (``record``; None: none will come)
        is known, and let ``record`` wait. Validated by the next, it is answered along the next
        one's trajectory, in whose window its frames lie (as SeqSLAM answers the middle of its
        window), with the evidence of both; consistent with its previous one only, along its
        own; consistent with neither, it is isolated: confidence 0."""
        waiting, self._waiting = self._waiting, record
        if waiting is None:
            return []
        own = waiting.trajectories[0][0]
        first = int(waiting.positions[0])
        if record is not None and record.consistent:
            along = [record.trajectories[0][0]]
            # Q reaching back before the next window far enough for a straight line extended
            # there to miss by more than the slack realignment corrects (speeds differ by up
            # to vmax - vmin): Q's own trajectory is tried too when its own window holds all of
            # Q (not when a featureless stretch cut it short)
            c = self.config
            seen = self._informative_rows(waiting.positions)
            if len(seen) and (record.window_start - seen[0]) * (c.vmax - c.vmin) > c.anchor_slack \
                    and waiting.window_start <= seen[0]:
                along.append(own)
            span = (min(record.window_start, first), int(record.positions[-1]))
            return self._frame_answers(waiting, "validated_by_next", along, record.evidence, span)
        span = (min(waiting.window_start, first), int(waiting.positions[-1]))
        if waiting.consistent:
            leaves = None
            if record is not None and self.config.leave_line:
                leaves = self._leaves_at(waiting, own, record.trajectories[0][0])
            return self._frame_answers(waiting, "consistent", [own], waiting.evidence, span, leaves)
        return self._frame_answers(waiting, "isolated", [own], 0.0, span)

    def _leaves_at(self, waiting: _FrameAnswer, own: Trajectory, elsewhere: Trajectory) -> int | None:
        """Where the route left Q's line: the query position from which Q's newest frames fit
        ``elsewhere`` (the next sequence's trajectory, inconsistent with Q's) better than Q's
        own line, by the split of Q's frames with the lowest total cost (ties: the latest).
        None when every frame fits Q's line best.

        Q's line is continued from the sequences before it; a jump in the route (the map
        holds the next stretch elsewhere) shows first in Q's newest frames, which the line
        still answers because most of its window is before the jump."""
        rows = self._informative_rows(waiting.positions)
        if not len(rows):
            return None
        fits = []
        for line in (own, elsewhere):
            at = line.at(rows)
            inside = (at >= 0) & (at < waiting.n_map)
            inside[inside] = waiting.map_informative[at[inside]]
            cost = np.full(len(rows), np.nan)
            cost[inside] = self._pairs.get(rows[inside], at[inside])
            fits.append(cost)
        both = np.concatenate(fits)
        if not np.isfinite(both).any():
            return None
        worst = float(np.nanmax(both))  # a frame a line cannot pair counts as the worst fit seen
        on_own, on_next = (np.where(np.isnan(f), worst, f) for f in fits)
        # total[k]: rows[:k] on Q's line, rows[k:] on the next one's
        total = np.concatenate([[0.0], np.cumsum(on_own)]) + np.concatenate([np.cumsum(on_next[::-1])[::-1], [0.0]])
        k = len(total) - 1 - int(np.argmin(total[::-1]))
        return None if k >= len(rows) else int(rows[k])

    def _informative_rows(self, positions: Iterable[int] | np.ndarray) -> np.ndarray:
        """(n,) int64: the query positions among ``positions`` whose frame is not featureless
        (the rows a sequence is compared over), in the given order."""
        return np.asarray([t for t in np.asarray(positions, dtype=np.int64).tolist() if self._informative[t]],
                          dtype=np.int64)

    def _blind_stretch(self, start: int, end: int) -> int:
        """The last query position of the latest run of more than alpha featureless frames in
        ``start..end`` (-1: none). Nothing tells how far the route went while nothing was
        seen, so a sequence is not compared across such a stretch."""
        t = end
        while t >= start:
            if self._informative[t]:
                t -= 1
                continue
            last = t
            while t >= start and not self._informative[t]:
                t -= 1
            if last - t > self.config.alpha:
                return last
        return -1

    def _realign(
        self, chosen: list[Trajectory], positions: np.ndarray, n_map: int, map_informative: np.ndarray
    ) -> Trajectory:
        """Level 3 (eq. 3.10 on Q's frames): Q's informative frames slid along the chosen
        trajectories and, as the thesis's template matching, at speed 1 through their
        middle, -anchor_slack..anchor_slack map frames; the placement they fit best.

        ``chosen`` is the trajectory answered along (the next sequence's when it validated
        this one), and Q's own when the next sequence's window does not reach far enough
        back to Q's first frame (a long Q in a slowly changing stretch): extended beyond its
        window a straight line drifts by up to ``vmax - vmin`` frames per frame. A placement may leave the
        map (the route goes on past the map's end, or past a stretch the map holds
        elsewhere) as long as at least half of Q's frames stay inside, as in level 2; it is
        scored on those. Ties: the first tried."""
        slack = self.config.anchor_slack
        rows = self._informative_rows(positions)
        if not len(rows):
            return chosen[0]
        middle = int(rows[len(rows) // 2])
        placements: list[Trajectory] = []
        for trajectory in dict.fromkeys(chosen):
            placements.append(trajectory)
            for shift in range(-slack, slack + 1):
                placements.append(Trajectory(trajectory.cost, middle, int(trajectory.at(middle)) + shift, 1.0,
                                             trajectory.rows))
                if shift:
                    placements.append(Trajectory(trajectory.cost, trajectory.anchor_query,
                                                 trajectory.anchor_map + shift, trajectory.speed, trajectory.rows))
        costs = []
        for placement in placements:  # each scored by level 2's rule: the line alone, no slack
            scored = best_trajectory(self._pairs, rows, placement.anchor_query, placement.anchor_map, 0,
                                     np.asarray([placement.speed]), n_map, map_informative)
            costs.append(np.inf if scored is None else scored.cost)
        if not np.isfinite(min(costs)):
            return chosen[0]
        return placements[int(np.argmin(costs))]

    def _compare(
        self, anchors: list[tuple[int, int, int]], rows: np.ndarray, n_map: int, map_informative: np.ndarray
    ) -> list[tuple[Trajectory, int]]:
        """Level 2, frame by frame: each anchor's best trajectory, best first (ties: level-1 order)."""
        c = self.config
        kept = anchors
        searched = [a for a in anchors if a[2] >= 0]
        if c.refine and len(searched) > c.refine:
            speed = np.asarray([min(max(1.0, c.vmin), c.vmax)])
            screened = []
            for k, (t, m, _) in enumerate(searched):
                found = best_trajectory(self._pairs, rows[-c.screen_frames:], t, m, c.anchor_slack, speed, n_map,
                                        map_informative)
                if found is not None:
                    screened.append((found.cost, k))
            kept = [searched[k] for _, k in sorted(screened)[: c.refine]] + [a for a in anchors if a[2] < 0]
        found = []
        for k, (t, m, source) in enumerate(kept):
            trajectory = best_trajectory(self._pairs, rows, t, m, c.anchor_slack, self._speeds, n_map, map_informative)
            if trajectory is not None:
                found.append((trajectory.cost, k, trajectory, source))
        return [(trajectory, source) for _, _, trajectory, source in sorted(found, key=lambda f: (f[0], f[1]))]

    def _frame_answers(
        self, record: _FrameAnswer, branch: str, along: list[Trajectory], confidence: float,
        span: tuple[int, int], leaves: int | None = None,
    ) -> list[Message]:
        """Level 3: Q's frames paired along ``along[0]``, or realigned along ``along`` (``realign``);
        ``span``: the query positions that chose the line (Q and the window compared), over
        which the line is checked against itself moved (``line_check``); frames from query
        position ``leaves`` on get no answer."""
        pm = self._map
        assert pm is not None
        c = self.config
        self._count(branch)
        best, source = record.trajectories[0]
        kept = record.positions if leaves is None else record.positions[record.positions < leaves]
        placement = along[0]
        if c.realign and len(kept):
            placement = self._realign(along, kept, record.n_map, record.map_informative)
        local = float("nan")
        if c.line_check and self._confidence_kind == "uniqueness" and confidence > 0:
            end = span[1] if leaves is None else min(span[1], leaves - 1)
            rows = self._informative_rows(range(span[0], end + 1))
            local = line_uniqueness(self._pairs, rows, placement, c.anchor_slack, c.uniqueness_window,
                                    record.n_map, record.map_informative)
            confidence = min(confidence, local)
        paired = placement.at(record.positions)
        others = [t.at(record.positions) for t, _ in record.trajectories[1:]]
        if source < 0:
            self._count("track_answers")
        out: list[Message] = [SequenceDecision(
            iteration=record.number, query_places=record.places, query_frames=record.frames,
            candidates=np.asarray([[s, int(t.at(record.positions[-1]))] for t, s in record.trajectories],
                                  dtype=np.int64).reshape(-1, 2),
            candidate_costs=np.asarray([t.cost for t, _ in record.trajectories], dtype=np.float64),
            branch=branch, first=int(paired[0]), last=int(paired[-1]), template_cost=best.cost,
            used_synthetic=source < 0, confidence=confidence, speed=placement.speed, line_uniqueness=local,
            left_line_at=-1 if leaves is None else int(self._order[leaves]),
        )]
        for k, frame in enumerate(record.frames.tolist()):
            if not self._informative[int(record.positions[k])]:
                self._count("featureless")
                out.append(LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                                      reason="featureless query frame (no edges to describe)"))
                continue
            if leaves is not None and record.positions[k] >= leaves:
                self._count("left_the_line")
                out.append(LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                                      reason="the route leaves the answered line here: the next sequence goes on "
                                      "elsewhere"))
                continue
            if not 0 <= paired[k] < record.n_map:
                self._count("outside_map")
                out.append(LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                                      reason="the chosen trajectory leaves the map here"))
                continue
            ranked = [int(paired[k]), *(int(o[k]) for o in others if 0 <= o[k] < record.n_map)]
            ranked = list(dict.fromkeys(ranked))[: self.config.candidates]
            matched = pm.map_frames_at(np.asarray(ranked, dtype=np.int64))
            out.append(LoopResult(
                frame=frame, match=int(matched[0]), confidence=confidence,
                accepted=confidence >= self._accept, candidates=matched,
            ))
        return out

    # --- faithful mode: level 3 -------------------------------------------------------------

    def _dispatch_all(self, dispatches: list[Dispatch]) -> list[Message]:
        out: list[Message] = []
        for dispatch in dispatches:
            out += self._level3(dispatch)
        return out

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
        informative = pm.informative(iteration.frames)
        offsets = pm.place_offsets()
        match = match_frames(
            query, informative, dispatch.sequence, offsets,
            lambda start, stop: pm.vectors(pm.map_frames(start, stop)), pm.metric,
            self._last_matched, dispatch.synthetic,
        )
        self._sequence_distances += match.n_distances
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
        matched = pm.map_frames_at(match.aligned)
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
                accepted=confidence >= self._accept,
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
            columns.append(pm.map_frames_at(positions))
        return [[int(col[k]) for col in columns] for k in range(n)]

    # --- bookkeeping ----------------------------------------------------------------------

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
        search = self._map.search_distances if self._map is not None else 0
        sequences = self._sequence_distances + self._pairs.computed  # faithful mode's, frames mode's
        stats: dict[str, float | int] = {
            "n_searches": self._counts.get("searches", 0),
            "n_query_sequences": self._n_iterations,
            "n_query_frames": self._query_frames,
            "n_distances": search + sequences,
            "n_distances_search": search,
            "n_distances_sequences": sequences,
        }
        keys = ("consistent", "validated_by_next", "rebuilt", "unresolved", "synthetic_frames") \
            if self.config.mode == "faithful" else ("consistent", "validated_by_next", "isolated", "inconsistent",
                                                     "track_answers", "outside_map", "left_the_line")
        for key in (*keys, "map_too_small", "no_candidate", "no_padding", "featureless", "no_answer_frames"):
            stats[f"n_{key}"] = self._counts.get(key, 0)
        return stats
