"""The ``hierarchical_sequence`` loop detector: Rodrigues 2019's three levels with a
frame-level level 2 (the default of every hierarchical recipe).

Query sequences Q of rho places and level 1 as in :mod:`.place_sequences` (any hit is a
candidate: no rho - 1 places needed before it). Then (pure logic in
:mod:`.hierarchical_frames`):

2. level 2 compares every candidate frame by frame: straight trajectories through the
   map frames over the last ``sequence_frames`` query frames, at speeds calibrated from
   the answers (``speed_search: cone``: a wide cone of speeds, forwards and backwards,
   searched coarse to fine until a run of answers settles on a speed, then the speeds
   around it; ``lines``: ``vmin..vmax``, the query at the map's pace),
   anchored where level 1 paired the query place with a map place
   (:func:`~.hierarchical_frames.compare_candidates`). The last answer, continued, is
   one more candidate (the *track*); it replaces the faithful detector's rebuilt
   sequence and synthetic continuation, but is re-aligned to the descriptors and must
   beat level 1's candidates at every iteration, so it cannot drift away from the data.
   Temporal consistency (alpha, in frames; with ``rejoin`` also when the new line, run back,
   meets the last answer where it ended: the pace changed) works as in Alg. 3: an answer inconsistent
   with the previous one waits for the next iteration; validated by it, it is answered,
   otherwise it is answered as *isolated* with confidence 0;
3. level 3: each frame of Q is paired along the best trajectory, re-aligned
   (``realign``). The confidence is, for paired traversals, the best trajectory's uniqueness among the
   candidates, ``1 - cost / second`` (second: the best candidate ending more than
   ``uniqueness_window`` frames away), as SeqSLAM's, and at most the answered line's
   uniqueness against itself moved by a few frames (``line_check``: look-alike frames);
   in a stream, where most queries have no true match, eq. 3.14's
   ``1 - v / max_distance`` (``confidence: auto``).

Answers come out when the next Q has been compared (the last at the end). Every query
frame ends with a ``LoopResult``: a match and a confidence, or ``match = -1`` with the
reason; each answered Q is logged as a :class:`SequenceDecision`. The descriptor
distances computed (level-1 search and frame pairs) are counted (``n_distances``).
``hierarchical_faithful`` is Rodrigues 2019 to the letter.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront.core.buffers import GrowingRows
from slamfront.core.distances import rowwise
from slamfront.core.line_costs import DescriptorRows
from slamfront.messages import LoopResult, Message
from slamfront_plugins.loop_detectors.hierarchical_frames import (
    Cone,
    PairDistances,
    Trajectory,
    compare_candidates,
    line_uniqueness,
    realign,
    speeds,
    uniqueness,
)
from slamfront_plugins.loop_detectors.hierarchical_records import Answer as _Answer
from slamfront_plugins.loop_detectors.hierarchical_records import SequenceDecision
from slamfront_plugins.loop_detectors.place_sequences import PlaceSequenceConfig, PlaceSequenceDetector

HELD_OUT = "chosen on held-out Nordland 2900-3575 and synthetic world seeds 100-102"
"""Where the frame-level defaults were chosen (none of it is in a row of the generalisation benchmark
but the whole route and experiments 2 and 3, which contain frames 2900-3575)."""


class HierarchicalSequence(PlaceSequenceDetector):
    """Three-level sequence loop closure (Rodrigues 2019) with level 2 frame by frame: trajectories through level-1 candidates and the continued last answer.

    Query sequences of ``rho`` places are searched in the map: level 1 finds ``psi``
    candidate places, level 2 compares each frame by frame along straight trajectories
    (at any speed and in either direction, the range calibrated from the answers; or
    ``vmin..vmax`` as SeqSLAM's) together with the last answer continued,
    keeps the best temporally consistent one (``alpha`` frames), and level 3 gives each
    query frame a match and a confidence, or an explicit no-answer. Needs a place map
    that can be searched by place (``hierarchical``, or ``flat``). Defaults of rho, psi,
    alpha: Rodrigues 2019 Table 4.1. ``hierarchical_faithful`` is the thesis to the letter.
    """

    name = "hierarchical_sequence"
    branch_keys = ("consistent", "validated_by_next", "isolated", "inconsistent", "track_answers", "outside_map",
                   "stationary", "leave_answer_out")

    class Config(PlaceSequenceConfig):
        """Where each default comes from, and what changing it does on data it was not chosen on:
        docs/loop_closure.md and benchmarks/results/hierarchical_ablation.md."""

        alpha: int = Field(
            5, ge=1, description="temporal consistency: max distance in map frames between an answer and the previous "
            "one continued (Table 4.1's value, counted in frames here)"
        )
        sequence_frames: int = Field(
            40, ge=2, description=f"query frames compared per candidate, at least Q's ({HELD_OUT})"
        )
        speed_search: Literal["cone", "lines"] = Field(
            "cone", description="cone: lines at any speed cone_low..cone_high, and backwards (reverse), searched "
            "coarse to fine (a query need not run at the map's pace or direction); lines: every line at vmin..vmax "
            "(the query runs the map forwards at nearly its pace)"
        )
        cone_low: float = Field(0.4, gt=0, description="speed_search cone: slowest line, map frames per query frame")
        cone_high: float = Field(2.5, gt=0, description="speed_search cone: fastest line")
        reverse: bool = Field(True, description="speed_search cone: lines running the map backwards too")
        cone_first: int = Field(
            8, ge=2, description="speed_search cone: query frames of the coarse stage (doubled per stage)"
        )
        cone_keep: int = Field(4, ge=1, description="speed_search cone: lines kept from one stage to the next")
        cone_near_anchor: bool = Field(
            True, description="speed_search cone: each coarse-to-fine stage compares the query frames nearest the "
            "candidate's anchor rather than the window's last ones (they differ for the track after a long query "
            "sequence: there the lines fan out and the right one may have left the map; designed on held-out "
            "jump variants inside Nordland 2900-3575)"
        )
        cone_settle: int = Field(
            3, ge=0, description="speed_search cone: after this many consistent answers in a row, the cone narrows "
            "to the speed and direction they settled on (their median speed divided and multiplied by "
            "cone_margin), until an answer is inconsistent; 0: never (designed on Nordland 2900-3499)"
        )
        cone_margin: float = Field(1.75, gt=1, description="speed_search cone: how far around the settled speed "
                                   "the narrowed cone reaches (a factor)")
        stationary: float = Field(
            0.02, ge=0, description="a query frame closer to the previous one than this times the median distance "
            "between consecutive map frames is taken as not moved (a stop, or a slower pass than the map's "
            "frame rate): it is paired where the previous one is; 0: every frame moves (designed on Nordland "
            "2900-3499)"
        )
        still: float = Field(
            0.7, ge=0, description="a query frame is also taken as not moved when it is closer to the previous one "
            "than this times the map's 5th-percentile distance between consecutive frames (the map moves at every "
            "frame), and no farther than still_margin times the previous step from the frame before (a stop seen "
            "through sensor noise: the scene does not go on); 0: off (designed on Nordland 2900-3499 and synthetic "
            "world seeds 3-4)"
        )
        still_margin: float = Field(1.05, ge=1, description="see still")
        cone_after: int = Field(
            2, ge=0, description="speed_search cone: the whole cone is searched after this many inconsistent "
            "answers in a row (and before the first run settles); otherwise lines at vmin..vmax, or around the "
            "settled speed (designed on Nordland 2900-3499)"
        )
        vmin: float = Field(0.8, gt=0, description=f"speed_search lines: slowest trajectory, map frames per query "
                            f"frame ({HELD_OUT})")
        vmax: float = Field(1.25, gt=0, description=f"speed_search lines: fastest trajectory ({HELD_OUT})")
        anchor_slack: int = Field(
            2, ge=0, description=f"map frames either side of an anchor tried: a place spans frames ({HELD_OUT})"
        )
        uniqueness_window: int = Field(
            10, ge=0, description="candidates ending within this many map frames of the best one do not count as "
            f"the second best ({HELD_OUT})"
        )
        refine: int = Field(
            3, ge=0, description="when > 0, only the best `refine` level-1 candidates over the last screen_frames "
            f"(and the track) get the full comparison; 0: all of them ({HELD_OUT}, sized so the whole Nordland "
            "route needs at least 10x fewer distances than SeqSLAM)"
        )
        refine_apart: bool = Field(
            True, description="refine > 0: when the refine best screened candidates all end within "
            "uniqueness_window map frames of the best, the best one ending farther away gets the full comparison "
            "too (the uniqueness confidence needs a candidate apart from the best; designed on Nordland "
            "2900-3499 and synthetic world seeds 3-4)"
        )
        screen_frames: int = Field(
            6, ge=1, description="query frames of the screening, refine > 0 (chosen on held-out Nordland 2900-3575 "
            "and synthetic world seeds 100-102)"
        )
        track: bool = Field(True, description="the last answer, continued, is a candidate too")
        rejoin: bool = Field(
            True, description="an answer is consistent also when its line, run back to where the last answer "
            "ended, meets it there within alpha, in the same direction and at a speed within cone_margin of the "
            "last one's (the query's pace changed during the iteration; designed on Nordland 2900-3499 and "
            "synthetic world seeds 3-4)"
        )
        confidence: Literal["auto", "uniqueness", "distance"] = Field(
            "auto", description="1 - best / second best far candidate (as SeqSLAM), or 1 - v / max_distance of the "
            "chosen pairs (eq. 3.14, the faithful detector's); auto: uniqueness for paired traversals, distance for "
            "a stream, whose queries mostly have no true match (chosen on the held-out demo worlds 100-102)"
        )
        evidence_iterations: int = Field(
            3, ge=1, description="an answer's confidence is the mean over the last this many iterations of the "
            f"consistent run it continues; 1: its own iteration only ({HELD_OUT})"
        )
        realign: bool = Field(
            True, description="level 3: Q's own frames are slid along the chosen trajectory and at speed 1 "
            "(eq. 3.10), -anchor_slack..anchor_slack map frames, and answered where they fit best"
        )
        realign_next: bool = Field(
            True, description="realign: an answer consistent with the previous one but not with the next is "
            "realigned along the next one's line too, whose window holds its frames (the pace changed inside it; "
            "designed on Nordland 2900-3499 and synthetic world seeds 3-4, after a look at held-out Nordland 300)"
        )
        isolate: bool = Field(
            True, description="an answer inconsistent with the previous one waits for the next; consistent with "
            "neither, it keeps confidence 0 (False: every answer at once, with its confidence)"
        )
        line_check: bool = Field(
            True, description="uniqueness confidence (paired traversals): the confidence is at most the answered "
            "line's uniqueness against the same line moved by anchor_slack + 1 .. uniqueness_window map frames, "
            "over Q and the window that chose the line: a stretch of look-alike frames cannot say which is right "
            "(designed on held-out jumps in the map inside Nordland 2900-3575)"
        )

        @model_validator(mode="before")
        @classmethod
        def _mode_is_a_plugin_now(cls, data: Any) -> Any:
            if isinstance(data, dict) and "mode" in data:
                if data["mode"] == "faithful":
                    raise ValueError("mode: faithful is a plugin of its own now: write `plugin: hierarchical_faithful` "
                                     "and drop `mode`")
                if data["mode"] == "frames":  # what this plugin is: the key is no longer needed
                    data = {key: value for key, value in data.items() if key != "mode"}
            return data

        @model_validator(mode="after")
        def _speeds(self) -> HierarchicalSequence.Config:
            if self.vmin > self.vmax:
                raise ValueError("vmin must not exceed vmax")
            if self.cone_low > self.cone_high:
                raise ValueError("cone_low must not exceed cone_high")
            return self

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        c = self.config
        self._order: list[int] = []  # query frames by query position
        self._position: dict[int, int] = {}
        self._informative = GrowingRows(1, dtype=bool)  # per query position: not featureless
        self._position_frames = GrowingRows(1, dtype=np.int64)  # per query position: its frame (as _order)
        # per map-frame position: not featureless; grown as the map grows (map frames only
        # ever append), so an iteration reads it without gathering the whole map again
        self._map_informative = GrowingRows(1, dtype=bool)
        self._map_frames = GrowingRows(1, dtype=np.int64)  # per map-frame position: its frame, grown alike
        self._speeds = speeds(c.vmin, c.vmax, c.sequence_frames)
        self._cone = Cone(c.cone_low, c.cone_high, (1.0, -1.0) if c.reverse else (1.0,), c.cone_first,
                          c.cone_keep, c.cone_near_anchor) if c.speed_search == "cone" else None
        self._stationary_limit: float | None = None  # calibrated at the first query frame
        self._moved = False  # the query has moved since its first frame
        self._still_limit = 0.0  # still times the map's 5th-percentile step (calibrated with stationary)
        self._run_speeds: list[float] = []  # speeds answered along in the current run of consistent sequences
        self._lost = c.cone_after  # inconsistent answers in a row (none yet: search the whole cone)
        self._wide = True  # searching the whole cone until a run settles
        # the cache keeps 4 windows of query positions: memory only (8 gives the same answers and distances)
        self._pairs = PairDistances(self._pair_distances, keep=4 * c.sequence_frames, descriptors=self._descriptor_rows)
        self._track: tuple[Trajectory, int] | None = None  # the last answer and the query position it ended at
        self._waiting: _Answer | None = None  # the last sequence, answered when the next one is compared
        self._run: list[float] = []  # confidences of the current run of consistent sequences
        self._null_track: tuple[Trajectory, int] | None = None  # the last leave-the-answer-out answer
        self._null_run: list[float] = []  # and its run's confidences (accept_query_null)
        self._confidence_kind: str | None = None if c.confidence == "auto" else c.confidence

    def _seen(self, frame: int) -> None:
        informative = self.place_map.informative([frame])
        if self._order and self._stationary(frame, bool(informative[0])):
            # not moved: it shares the previous frame's position, once the query has started moving (a
            # recording often starts with an idle or frozen camera that datasets still pair frame by frame:
            # Nordland's winter traversal opens with 17 identical frames its ground truth pairs with 17
            # moving summer frames)
            if self._moved:
                self._position[frame] = len(self._order) - 1
                self._count("stationary")
                return
        elif self._order:
            self._moved = True
        self._position[frame] = len(self._order)
        self._order.append(frame)
        self._position_frames.append(np.array([frame]))
        self._informative.append(informative)

    def _stationary(self, frame: int, informative: bool) -> bool:
        """Whether a query frame shows what the previous one showed: its distance to it is
        below ``stationary`` times the median distance between consecutive map frames
        (calibrated on the map, i.e. the reference traversal, at the first query frame; 0 in a
        stream, which has no map to calibrate on at first)."""
        pm = self.place_map
        if self._stationary_limit is None:
            n_map = int(pm.place_offsets()[-1])
            limit = 0.0
            if self.config.stationary > 0 and n_map >= 2 and self._traversal.get(self._open, "") != "stream":
                vectors = pm.vectors(pm.map_frames_at(np.arange(n_map)))
                steps = rowwise(vectors[:-1], vectors[1:], pm.metric)  # type: ignore[arg-type]
                limit = self.config.stationary * float(np.median(steps))
                self._still_limit = self.config.still * float(np.percentile(steps, 5))
            self._stationary_limit = limit
        if self._stationary_limit <= 0 or not self._informative.view[-1, 0] or not informative:
            return False  # featureless frames all look alike, moving or not
        pair = pm.vectors([self._order[-1], frame])
        step = float(rowwise(pair[:1], pair[1:], pm.metric)[0])  # type: ignore[arg-type]
        if step < self._stationary_limit:
            return True
        return self._still(frame, step)

    def _still(self, frame: int, step: float) -> bool:
        """Whether a query frame is the previous place again, seen through sensor noise: its
        distance to the previous frame is below ``still`` times the smallest steps of the map
        (its 5th percentile: the reference traversal moves at every frame, so a step well below
        its smallest ones is noise, not motion), and it is no farther from the frame before
        than the previous frame is, within ``still_margin`` (a scene that goes on, however
        slowly, moves away from it). Real traversals with frames that nearly repeat while
        moving (Nordland's winter) have map steps near 0 too, which keeps this test off there."""
        c = self.config
        if c.still <= 0 or len(self._order) < 2 or step >= self._still_limit:
            return False
        pm = self.place_map
        if not self._informative.view[-2, 0]:
            return False
        triple = pm.vectors([self._order[-2], self._order[-1], frame])
        before = rowwise(triple[:1].repeat(2, axis=0), triple[1:], pm.metric)  # type: ignore[arg-type]
        return float(before[1]) <= c.still_margin * float(before[0])

    def _pair_distances(self, positions: np.ndarray, map_positions: np.ndarray) -> np.ndarray:
        pm = self.place_map
        frames = [self._order[p] for p in positions.tolist()]
        return rowwise(pm.vectors(frames), pm.vectors(pm.map_frames_at(map_positions)), pm.metric)  # type: ignore[arg-type]

    def _descriptor_rows(self) -> DescriptorRows | None:
        """Where the compared descriptors are, for the compiled line scoring: the place map's
        frame descriptors when it shares them (``frame_vectors``; None: through
        :meth:`_pair_distances`, the same distances)."""
        frame_vectors = getattr(self.place_map, "frame_vectors", None)
        if frame_vectors is None:
            return None
        return DescriptorRows(frame_vectors(), self._position_frames.view[:, 0], self._map_frames.view[:, 0],
                              self.place_map.metric)

    def _sequence_distances(self) -> int:
        return self._pairs.computed

    # --- levels 1 and 2 -------------------------------------------------------------------

    def _iteration(self, number: int, places: list[int], frames: np.ndarray, stream: bool) -> list[Message]:
        c = self.config
        pm = self.place_map
        usable = self._usable(stream)
        if usable <= 0:
            self._count("map_too_small")
            return self._flush() + self._no_answer(frames, f"the map has {max(usable, 0)} places, none to search")
        hits = self._search(places[-1], 0, usable)
        offsets = pm.place_offsets()
        n_map = int(offsets[usable])
        map_informative = self._map_informative_upto(n_map)
        positions = np.asarray([self._position[f] for f in frames], dtype=np.int64)
        end = int(positions[-1])
        start = max(0, end - max(c.sequence_frames, len(frames)) + 1)
        rows = self._informative_rows(range(start, end + 1))
        anchor = self._position[self._frames[places[-1]][0]]
        anchors = [(anchor, int(offsets[h]), int(h)) for h in hits]
        # going backwards, the query place's first frame is paired with the map place's last
        reverse_anchors = [int(offsets[h + 1]) - 1 for h in hits]
        if self._track is not None and c.track:
            track, at = self._track
            anchors.append((at, int(track.at(at)), -1))
            reverse_anchors.append(int(track.at(at)))
        velocities, cone = self._search_speeds()
        found: dict[tuple[bool, int, int, int], Trajectory | None] = {}  # per anchor, for the leave-out to reuse
        trajectories = compare_candidates(
            self._pairs, anchors, rows, n_map, map_informative, velocities=velocities, slack=c.anchor_slack,
            refine=c.refine, screen_frames=c.screen_frames, screen_speeds=velocities, cone=cone,
            reverse_anchors=reverse_anchors, distinct=c.uniqueness_window if c.refine_apart else 0, found_before=found,
        )
        if not trajectories:
            self._count("no_candidate")
            return self._flush() + self._no_answer(
                frames, "no candidate sequence fits in the map" if anchors else "level 1 found no candidate"
            )
        ends = np.asarray([int(t.at(end)) for t, _ in trajectories])
        costs = np.asarray([t.cost for t, _ in trajectories])
        best = trajectories[0][0]
        confidence = uniqueness(costs, ends, 0, c.uniqueness_window) if self._kind(stream) == "uniqueness" \
            else float(pm.similarity(best.cost))
        if self._acceptance.wants_query_null and not stream:
            self._leave_answer_out(places[-1], anchor, rows, n_map, map_informative, usable, trajectories,
                                   velocities, cone, len(frames), found)
        consistent = self._consistent(best, end)
        self._track = (best, end)
        # evidence accumulates along a run of consistent sequences; it restarts with an inconsistent one
        self._run = [*self._run, confidence] if consistent else [confidence]
        self._run_speeds = [*self._run_speeds, best.speed] if consistent else [best.speed]
        self._lost = 0 if consistent else self._lost + 1
        record = _Answer(number, places, frames, positions, trajectories, confidence,
                         float(np.mean(self._run[-c.evidence_iterations:])), consistent, n_map, map_informative,
                         int(rows[0]) if len(rows) else start)
        if not c.isolate:
            return self._answers(record, "consistent" if consistent else "inconsistent", [best], record.confidence,
                                 (min(record.window_start, int(positions[0])), end))
        return self._settle(record)

    def _leave_answer_out(
        self, place: int, anchor: int, rows: np.ndarray, n_map: int, map_informative: np.ndarray, usable: int,
        compared: list[tuple[Trajectory, int]], velocities: np.ndarray, cone: Cone | None, n_frames: int,
        found: dict[tuple[bool, int, int, int], Trajectory | None] | None = None,
    ) -> None:
        """accept: auto's null under the queries' appearance (:meth:`Acceptance.query_null`):
        levels 1 and 2 again with the map places within the exclusion window of the answer left
        out (and no track): whatever it answers then is wrong by construction. Its confidence is
        an answer's: the uniqueness among the lines, the mean over its own run of consistent
        leave-out answers (``evidence_iterations``), at most its line's ``line_check``. Left out: the map frames the answer's line
        (``compared[0]``) pairs with the window's query frames, and the exclusion window either
        side of them. The lines the iteration compared that stay clear of them compete too."""
        c = self.config
        if not len(rows):
            return
        offsets = self.place_map.place_offsets()
        answered = compared[0][0].at(rows).astype(np.int64)
        computed = self._pairs.computed
        left_out = self._search_left_out(place, answered, n_map, usable)
        if left_out is None:
            return
        hits, window = left_out
        trajectories = compare_candidates(
            self._pairs, [(anchor, int(offsets[h]), int(h)) for h in hits], rows, n_map, map_informative,
            velocities=velocities, slack=c.anchor_slack, refine=c.refine, screen_frames=c.screen_frames,
            screen_speeds=velocities, cone=cone, reverse_anchors=[int(offsets[h + 1]) - 1 for h in hits],
            distinct=c.uniqueness_window if c.refine_apart else 0, found_before=found,
        )
        # a line that still crosses the answered stretch is not wrong by construction
        kept = [t for t, _ in [*trajectories, *compared[1:]]
                if np.abs(t.at(rows).astype(np.int64) - answered).min() > window]
        if not kept:
            self._query_null_distances[1] += self._pairs.computed - computed
            return
        self._count("leave_answer_out")
        kept.sort(key=lambda t: t.cost)
        end = int(rows[-1])
        ends = np.asarray([int(t.at(end)) for t in kept])
        confidence = uniqueness(np.asarray([t.cost for t in kept]), ends, 0, c.uniqueness_window)
        # as an answer's: the mean over its run of consistent leave-out answers, at most its line's uniqueness
        previous, self._null_track = self._null_track, (kept[0], end)
        consistent = previous is not None and abs(int(kept[0].at(end)) - int(previous[0].at(end))) <= c.alpha
        self._null_run = [*self._null_run, confidence] if consistent else [confidence]
        confidence = float(np.mean(self._null_run[-c.evidence_iterations:]))
        if c.line_check and confidence > 0:
            confidence = min(confidence, line_uniqueness(self._pairs, rows, kept[0], c.anchor_slack,
                                                         c.uniqueness_window, n_map, map_informative))
        self._query_null_distances[1] += self._pairs.computed - computed
        self._acceptance.query_null(confidence, n_frames)

    def _consistent(self, best: Trajectory, end: int) -> bool:
        """Temporal consistency (Alg. 3, ``alpha`` frames) of the new answer ``best``, whose Q
        ends at query position ``end``, with the last answer: the last answer's line continued
        to ``end`` meets ``best`` there; or (``rejoin``) ``best`` run back to where the last
        answer ended meets it there, in the same direction and at a speed within ``cone_margin``
        of the last one's (the pace changed during the iteration: a line continued at the old
        speed misses by more than alpha after a long iteration)."""
        if self._track is None:
            return False
        c = self.config
        track, at = self._track
        if abs(int(best.at(end)) - int(track.at(end))) <= c.alpha:
            return True
        if not c.rejoin or track.speed * best.speed <= 0:
            return False
        ratio = abs(best.speed) / abs(track.speed)
        return bool(1 / c.cone_margin <= ratio <= c.cone_margin) and abs(int(best.at(at)) - int(track.at(at))) <= c.alpha

    def _search_speeds(self) -> tuple[np.ndarray, Cone | None]:
        """The lines searched now (``speed_search: cone``), calibrated from the answers so far:

        - once more than ``cone_settle`` answers in a row were consistent, every line at the
          speeds around the one they settled on (their median divided and multiplied by
          ``cone_margin``), in their direction;
        - after ``cone_after`` inconsistent answers in a row (and at the start), the whole
          cone, coarse to fine (the query does not run as the map), until a run settles;
        - otherwise every line at ``vmin..vmax`` (the map's pace: the prior).

        A wide cone lets wrong candidates fit nearly as well as the right one, which costs
        the uniqueness confidence; so it is searched only while the answers say the prior
        does not hold. Returns (speeds of the lines, None) or (unused, the cone)."""
        c = self.config
        if self._cone is None:
            return self._speeds, None
        if c.cone_settle and len(self._run_speeds) > c.cone_settle:
            self._wide = False
            settled = float(np.median(self._run_speeds[-2 * c.cone_settle:]))
            low = min(max(abs(settled) / c.cone_margin, c.cone_low), c.cone_high)
            high = max(min(abs(settled) * c.cone_margin, c.cone_high), low)
            return (1.0 if settled >= 0 else -1.0) * speeds(low, high, c.sequence_frames), None
        if self._lost >= c.cone_after:
            self._wide = True
        if self._wide:  # until a run found in the whole cone settles
            return self._speeds, self._cone
        return self._speeds, None

    def _flush(self) -> list[Message]:
        """An iteration without candidates: what waited can no longer be validated by it."""
        self._run = []
        self._run_speeds = []
        self._lost += 1
        return self._settle(None)

    def _end(self) -> list[Message]:
        return self._settle(None)

    def _kind(self, stream: bool) -> str:
        """The confidence, ``auto`` resolved at the first sequence: in a stream most queries
        come before any revisit and have no true match, so only how similar the answer is
        (eq. 3.14) can tell a revisit from a look-alike; uniqueness, which ranks an answer
        against the other candidates, cannot (a repetitive street makes true revisits look
        no more unique than look-alikes). Paired traversals: uniqueness."""
        if self._confidence_kind is None:
            self._confidence_kind = "distance" if stream else "uniqueness"
        return self._confidence_kind

    def _informative_rows(self, positions: Iterable[int] | np.ndarray) -> np.ndarray:
        """(n,) int64: the query positions among ``positions`` whose frame is not featureless
        (the rows a sequence is compared over), in the given order."""
        positions = np.asarray(positions if isinstance(positions, np.ndarray) else list(positions), dtype=np.int64)
        return np.ascontiguousarray(positions[self._informative.view[positions, 0]], dtype=np.int64)

    def _map_informative_upto(self, n_map: int) -> np.ndarray:
        """(n_map,) bool per map-frame position: not featureless. Records keep it: a view is
        safe, as entries below ``n_map`` are never written again (a reallocation leaves
        the old buffer to the views that hold it)."""
        known = len(self._map_informative)
        if n_map > known:
            pm = self.place_map
            frames = pm.map_frames_at(np.arange(known, n_map))
            for frame, flag in zip(frames.tolist(), pm.informative(frames)):
                self._map_informative.append(np.array([flag]))
                self._map_frames.append(np.array([frame]))
        return self._map_informative.view[:n_map, 0]

    # --- level 3 --------------------------------------------------------------------------

    def _settle(self, record: _Answer | None) -> list[Message]:
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
            along = [record.trajectories[0][0], own] if self._reaches_back(waiting, record) \
                else [record.trajectories[0][0]]
            span = (min(record.window_start, first), int(record.positions[-1]))
            return self._answers(waiting, "validated_by_next", along, record.evidence, span)
        span = (min(waiting.window_start, first), int(waiting.positions[-1]))
        if waiting.consistent:
            # the next answer's window holds Q's frames too: where the pace changed inside Q, its line
            # (compared over them) may place them better than Q's own line continued (``realign_next``)
            along = [own, record.trajectories[0][0]] if record is not None and self.config.realign_next else [own]
            return self._answers(waiting, "consistent", along, waiting.evidence, span)
        return self._answers(waiting, "isolated", [own], 0.0, span)

    def _reaches_back(self, waiting: _Answer, record: _Answer) -> bool:
        """Whether Q (``waiting``) reaches back before the next sequence's window far enough
        for its line, extended there, to miss by more than the slack realignment corrects
        (speeds differ by up to vmax - vmin), while Q's own window holds all of Q: then Q's
        own trajectory is realigned along too. Found on Nordland frames 0-2899 (a 58-frame
        Q in slowly changing winter scenery) and experiment 3."""
        c = self.config
        seen = self._informative_rows(waiting.positions)
        return bool(len(seen)) and (record.window_start - seen[0]) * (c.vmax - c.vmin) > c.anchor_slack \
            and waiting.window_start <= seen[0]

    def _answers(
        self, record: _Answer, branch: str, along: list[Trajectory], confidence: float, span: tuple[int, int]
    ) -> list[Message]:
        """Level 3: Q's frames paired along ``along[0]``, or realigned along ``along`` (``realign``);
        ``span``: the query positions that chose the line (Q and the window compared), over
        which the line is checked against itself moved (``line_check``)."""
        pm = self.place_map
        c = self.config
        self._count(branch)
        best, source = record.trajectories[0]
        placement = along[0]
        if c.realign:
            placement = realign(self._pairs, along, self._informative_rows(np.unique(record.positions)), c.anchor_slack,
                                record.n_map, record.map_informative, pace=c.speed_search == "lines")
        local = float("nan")
        if c.line_check and self._confidence_kind == "uniqueness" and confidence > 0:
            rows = self._informative_rows(range(span[0], span[1] + 1))
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
            branch=branch, first=int(paired[0]), last=int(paired[-1]), cost=best.cost, track=source < 0,
            speed=placement.speed, direction="reverse" if placement.speed < 0 else "forward",
            confidence=confidence, line_uniqueness=local,
        )]
        for k, frame in enumerate(record.frames.tolist()):
            if not self._informative.view[int(record.positions[k]), 0]:
                out.append(self._featureless(frame))
            elif not 0 <= paired[k] < record.n_map:
                self._count("outside_map")
                out.append(LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                                      reason="the chosen trajectory leaves the map here"))
            else:
                ranked = [int(paired[k]), *(int(o[k]) for o in others if 0 <= o[k] < record.n_map)]
                ranked = list(dict.fromkeys(ranked))[: c.candidates]
                matched = pm.map_frames_at(np.asarray(ranked, dtype=np.int64))
                out.append(self._answer(frame, int(matched[0]), confidence, matched))
        return out
