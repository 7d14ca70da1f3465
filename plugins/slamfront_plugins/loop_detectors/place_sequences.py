"""What both hierarchical detectors share: Alg. 1's loop over query places, and level 1
(Rodrigues 2019 §3.2, §3.2.1).

Online, as in Alg. 1: query frames arrive one at a time and the place map groups them
into places. When the rho-th place since the last query sequence is complete (the first
frame of the next place arrived), the last rho places form the query sequence Q and one
iteration runs; a stream's Q (or, with ``query_joins_map``, any Q) then joins the map
(Alg. 1 line 14). Level 1 searches the psi map places nearest to ``R(q_rho)``, the
representative of Q's newest place. What follows level 1 is each detector's own
(:mod:`.hierarchical_faithful`, :mod:`.hierarchical_sequence`).

The place map is read only through :class:`slamfront.plugin.SearchablePlaceMap`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
from pydantic import Field

from slamfront import LoopDetector, Plugin, PluginError, StageInputs
from slamfront.acceptance import Acceptance, AcceptanceConfig
from slamfront.core.operating_point import exclusion_window
from slamfront.messages import LoopResult, Message, PlaceAssignment
from slamfront.plugin import SearchablePlaceMap

CALIBRATION_QUERY_FRAMES = 600
"""accept: auto with a reference: at most this many reference frames (its second half, at
most) are answered against the reference before them, outside ``accept_exclusion_frames``."""


class PlaceSequenceConfig(AcceptanceConfig):
    """The parameters both hierarchical detectors share (defaults: Rodrigues 2019 Table 4.1)."""

    legacy_accept_key = "accept_confidence"

    rho: int = Field(5, ge=1, description="places per query sequence |Q| = |F| (Table 4.1)")
    psi: int = Field(10, ge=1, description="nearest neighbours searched at level 1 (Table 4.1)")
    query_joins_map: bool = Field(
        False, description="query places join the map after their iteration (Rodrigues 2019 §4.4 keeps the map "
        "to the reference traversal; stream traversals always join)"
    )
    exclude_recent_places: int = Field(
        20, ge=0, description="stream traversals: the most recent map places are not loop candidates"
    )
    candidates: int = Field(10, ge=1, description="ranked candidate frames reported per query (recall@K)")


class PlaceSequenceDetector(LoopDetector):
    """Base of the hierarchical detectors: query places gathered into sequences of rho, and level 1.

    A subclass implements :meth:`_iteration` (levels 2 and 3 for one Q) and :meth:`_end`
    (answers still pending when the traversal ends). Whether an answer is accepted is
    decided here, in :meth:`_answer`, at the operating point (``accept``; auto: calibrated
    on the reference answered against its own earlier part with the detector itself, or on
    a stream's first frames, :mod:`slamfront.acceptance`).
    """

    requires = ("descriptor", "place_map")
    branch_keys: tuple[str, ...] = ()
    """Counters a subclass reports in its statistics (``n_<key>``), besides the shared ones."""

    Config = PlaceSequenceConfig

    def __init__(self, config: PlaceSequenceConfig | None = None) -> None:
        super().__init__(config)
        self._map: SearchablePlaceMap | None = None
        self._awaiting: deque[tuple[int, str]] = deque()  # (frame, traversal) of query frames not placed yet
        self._open: int | None = None  # the query place still growing
        self._pending: list[int] = []  # closed query places not yet in a Q
        self._frames: dict[int, list[int]] = {}  # frames of the open and pending query places
        self._traversal: dict[int, str] = {}  # and their traversal
        self._n_iterations = 0
        self._counts: dict[str, int] = {}
        self._query_frames = 0
        self._acceptance = Acceptance(self.config, self.name)
        self._query_position: dict[int, int] = {}  # query frame -> its position among the query frames
        self._stream = False
        self._horizon: int | None = None
        """Calibration only: map places at positions from this one on are out of reach."""
        self._calibration_distances = (0, 0)  # (level-1 search, sequences) computed by the calibration
        self._calibration_seen = (0, 0)  # (passes, wrong decisions; -1: not grouped) of the calibration
        self._query_null_distances = [0, 0]  # (level-1 search, sequences) computed by the queries' null
        self._undecided: dict[int, tuple[float | None, float | None]] = {}
        """accept_query_null_wait: query frame -> (score, distinctiveness) of answers not decided yet."""
        self._held_back: list[LoopResult] = []  # answers held back until those are decided
        self._n_waited = 0

    def check(self, stages: Mapping[str, Plugin]) -> None:
        place_map = stages.get("place_map")
        if not isinstance(place_map, SearchablePlaceMap):
            found = place_map.name if place_map is not None else "none"
            raise PluginError(f"needs a place map it can search by place, such as 'hierarchical' or 'flat' (found "
                              f"{found!r}, which does not implement SearchablePlaceMap)")

    @property
    def place_map(self) -> SearchablePlaceMap:
        assert self._map is not None, "no frame has been processed yet"
        return self._map

    # --- the stream (Alg. 1) --------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        self._map = inputs.stages["place_map"]  # type: ignore[assignment]
        out: list[Message] = []
        if inputs.frame.traversal != "reference":
            if not self._query_frames and not self._awaiting:  # the first query frame
                self._stream = inputs.frame.traversal == "stream"
                if not self._stream and self._acceptance.auto:
                    self._calibrate_on_reference()
            self._awaiting.append((inputs.frame.index, inputs.frame.traversal))
        # the place map may place several frames at once (those it held while calibrating)
        for assignment in inputs.outputs.get("place_map", ()):
            if isinstance(assignment, PlaceAssignment) and self._awaiting and assignment.frame == self._awaiting[0][0]:
                _, traversal = self._awaiting.popleft()
                out += self._placed(assignment.frame, traversal, assignment.place, assignment.new_place)
        out = self._release(out)
        return [*self._acceptance.messages(), *out]

    def finish(self) -> Sequence[Message]:
        out = self._release(self._finish(), ending=True)
        self._acceptance.finish()
        return [*self._acceptance.messages(), *out]

    def _finish(self) -> list[Message]:
        out: list[Message] = []
        if self._map is None:
            return out
        while self._awaiting:  # placed by the place map's own finish (a run shorter than its calibration)
            frame, traversal = self._awaiting.popleft()
            place = self._map.place_of(frame)
            out += self._placed(frame, traversal, place, place != self._open)
        if self._open is not None:
            out += self._close(self._open)
            self._open = None
        out += self._end()
        for place in self._pending:
            out += self._no_answer(self._frames_of([place]), "traversal ended before its query sequence was complete")
        self._pending = []
        return out

    def _placed(self, frame: int, traversal: str, place: int, new_place: bool) -> list[Message]:
        self._query_position[frame] = self._query_frames
        self._query_frames += 1
        self._seen(frame)
        out: list[Message] = []
        if new_place:
            if self._open is not None:
                out += self._close(self._open)
            self._open = place
            self._frames[place], self._traversal[place] = [], traversal
        self._frames[place].append(frame)
        return out

    def _seen(self, frame: int) -> None:
        """A query frame was placed (in order): for a subclass's own bookkeeping."""

    def _close(self, place: int) -> list[Message]:
        """A query place is complete; run an iteration when it completes a Q."""
        self._pending.append(place)
        if len(self._pending) < self.config.rho:
            return []
        places, self._pending = self._pending, []
        self._n_iterations += 1
        stream = self._traversal[places[-1]] == "stream"
        out = self._iteration(self._n_iterations, places, self._frames_of(places), stream)
        if stream or self.config.query_joins_map:
            for p in places:  # Alg. 1 line 14: Q joins the map after its iteration
                self.place_map.commit(p)
        for p in places:
            del self._frames[p], self._traversal[p]
        return out

    def _iteration(self, number: int, places: list[int], frames: np.ndarray, stream: bool) -> list[Message]:
        """Levels 2 and 3 for query sequence ``number`` (its places and their frames, in order)."""
        raise NotImplementedError

    def _end(self) -> list[Message]:
        """The traversal ended: answer what still waits."""
        return []

    # --- the operating point ----------------------------------------------------------------

    def _calibrate_on_reference(self) -> None:
        """accept: auto, paired traversals: this detector (a copy, same parameters) answers the
        reference's last frames (its last two thirds, at most ``CALIBRATION_QUERY_FRAMES``; a
        subclass may add passes, :meth:`_calibration_starts`) as queries, as a stream, against the
        reference places ending before the frames it compares (``sequence_frames``) and the
        exclusion window (``accept_exclusion_frames``, at most a tenth of the reference): a
        traversal does not revisit itself, so every answer more than two windows away is wrong,
        and their confidences set the threshold."""
        pm = self.place_map
        n = int(pm.place_offsets()[-1])
        window = exclusion_window(n, self.config.accept_exclusion_frames)
        searched = pm.search_distances
        frames = pm.map_frames_at(np.arange(n)).tolist()
        position = {f: k for k, f in enumerate(frames)}
        own: list[float] = []
        scored: list[float] = []
        distinct: list[float] = []
        decisions: list[float] | None = []
        sequences = 0
        enough = self._calibration_decisions()
        passes = 0
        for start in self._calibration_starts(n, n - min(2 * n // 3, CALIBRATION_QUERY_FRAMES)):
            copy, out = self._reference_pass(frames, start, window)
            # an answer within two windows of its frame may be the query's own stretch seen just
            # before: only those farther away are known to be wrong
            scores = self._reference_scores(copy)
            wrong = [m for m in out if isinstance(m, LoopResult) and m.match >= 0
                     and position[m.frame] - position.get(m.match, -n) > 2 * window]
            own += [m.confidence for m in wrong]
            scored += [scores.get(m.frame, m.confidence) for m in wrong]
            wrong_frames = {m.frame for m in wrong}
            found = self._wrong_decisions(copy, wrong_frames)
            decisions = None if found is None or decisions is None else decisions + found
            distinct += self._wrong_distinct(copy, wrong_frames)
            sequences += copy._sequence_distances()
            passes += 1
            # a later pass only when those before saw no wrong answer (or, when the subclass asks for
            # ``enough`` wrong decisions, fewer than that)
            if own and (enough <= 1 or (decisions is not None and len(decisions) >= enough)):
                break
        self._calibration_distances = (pm.search_distances - searched, sequences)
        self._calibration_seen = (passes, -1 if decisions is None else len(decisions))
        self._acceptance.calibrate_reference(own, scored, decisions if self._discounts_outlier() else None)
        if self._acceptance.distinct:
            self._acceptance.calibrate_distinct(distinct, own)

    def _calibration_starts(self, n: int, start: int) -> list[int]:
        """accept: auto: where the calibration passes over the reference (``n`` frames) start, in
        the order tried: a pass runs only when those before it saw no wrong answer (``start``: the
        last two thirds, at most ``CALIBRATION_QUERY_FRAMES``); here one pass."""
        return [start]

    def _reference_pass(self, frames: list[int], start: int, window: int) -> tuple[PlaceSequenceDetector, list[Message]]:
        """One calibration pass: a copy of this detector answers the reference ``frames`` from
        position ``start`` on, each against the places ending ``window`` (and ``sequence_frames``)
        before it. Returns the copy and its answers."""
        pm = self.place_map
        offsets = pm.place_offsets()
        reach = window + int(getattr(self.config, "sequence_frames", 0) or 0)
        copy = type(self)(self.config.model_copy(update={"accept": 0.0}))
        copy._map = pm
        out: list[Message] = []
        previous = None
        for k in range(start, len(frames)):
            # the map in reach ends the compared window and the exclusion window before this frame
            copy._horizon = max(0, int(np.searchsorted(offsets, k - reach, side="right")) - 1)
            place = pm.place_of(frames[k])
            out += copy._placed(frames[k], "query", place, place != previous)
            previous = place
        out += copy._finish()
        return copy, out

    def _wrong_decisions(self, copy: PlaceSequenceDetector, wrong: set[int]) -> list[float] | None:
        """accept: auto: the confidences of the calibration copy's decisions that gave the ``wrong``
        frames, one per decision (a detector that judges a sequence of frames at once); None: this
        detector's answers are not grouped in decisions."""
        return None

    def _wrong_distinct(self, copy: PlaceSequenceDetector, wrong: set[int]) -> list[float]:
        """accept: auto with ``accept_score: ..._or_distinct``: the distinctiveness of each of the
        calibration copy's decisions that gave the ``wrong`` frames (none: not offered)."""
        return []

    def _calibration_decisions(self) -> int:
        """accept: auto: the calibration runs its passes (:meth:`_calibration_starts`) until it has
        seen this many wrong decisions (:meth:`_wrong_decisions`); 1: until any wrong answer."""
        return 1

    def _discounts_outlier(self) -> bool:
        """accept: auto: whether the threshold discounts an outlier among the wrong decisions
        (:func:`slamfront.core.operating_point.outlier_discounted_threshold`)."""
        return False

    def _reference_scores(self, copy: PlaceSequenceDetector) -> dict[int, float]:
        """accept: auto: what the threshold is compared with for the calibration copy's answers,
        by frame, when it is not their confidence (a subclass's supported confidence)."""
        return {}

    # --- level 1 --------------------------------------------------------------------------

    def _n_map_places(self) -> int:
        """Map places in reach (all of them, but while calibrating)."""
        n_map_places = len(self.place_map.place_offsets()) - 1
        return n_map_places if self._horizon is None else min(n_map_places, self._horizon)

    def _usable(self, stream: bool) -> int:
        """How many map places level 1 may search (positions 0..usable-1): in a stream, not
        the ``exclude_recent_places`` most recent (the robot just saw them)."""
        return self._n_map_places() - (self.config.exclude_recent_places if stream else 0)

    def _search(self, place: int, lo: int, usable: int) -> np.ndarray:
        """Level 1 (Alg. 2): the psi map places nearest to the place's representative among
        map positions ``lo..usable-1``, nearest first."""
        pm = self.place_map
        self._count("searches")
        hits, _ = pm.nearest(pm.representatives([place])[0], self.config.psi, lo=lo, hi=usable - 1)
        return np.asarray(hits, dtype=np.int64)

    def _search_left_out(self, place: int, answered: np.ndarray, n_map: int, usable: int,
                         lead: int = 0) -> tuple[np.ndarray, int] | None:
        """Level 1 for accept: auto's queries' null (:meth:`Acceptance.query_null`): the psi map
        places nearest to the place's representative, nearest first, with the map places within
        the exclusion window (``accept_exclusion_frames`` of ``n_map`` frames) of the ``answered``
        map-frame positions left out; a hit needs ``lead`` places before it on its own side (a
        sequence ending there stays clear). Returns ``(hits, window)``, or None when nothing is
        left; its distances count as the null's."""
        pm = self.place_map
        offsets = pm.place_offsets()
        window = exclusion_window(n_map, self.config.accept_exclusion_frames)
        first = max(0, int(np.searchsorted(offsets, int(answered.min()) - window, side="right")) - 1)
        last = int(np.searchsorted(offsets, int(answered.max()) + window, side="right")) - 1
        vector = pm.representatives([place])[0]
        found: list[tuple[np.ndarray, np.ndarray]] = []
        searched = pm.search_distances
        for lo, hi in ((lead, first - 1), (last + 1 + lead, usable - 1)):
            if lo <= hi:
                found.append(pm.nearest(vector, self.config.psi, lo=lo, hi=hi))
        self._query_null_distances[0] += pm.search_distances - searched
        if not found:
            return None
        hits = np.concatenate([np.asarray(h, dtype=np.int64) for h, _ in found])
        near = np.concatenate([np.asarray(d, dtype=np.float64) for _, d in found])
        return hits[np.argsort(near, kind="stable")][: self.config.psi], window

    # --- answers and bookkeeping -------------------------------------------------------------

    def _answer(self, frame: int, match: int, confidence: float, candidates: np.ndarray,
                score: float | None = None, distinct: float | None = None) -> LoopResult:
        """The one place an answer is accepted: at the operating point (in a stream, answers to
        its first ``accept_calibration_frames`` frames calibrate it and are not accepted), on
        ``score`` when given (paired traversals: :meth:`Acceptance.score`), else the confidence,
        or on ``distinct`` (its distinctiveness) when the operating point takes it."""
        if self._stream:
            accepted = self._acceptance.stream_answer(self._query_position[frame], confidence)
        elif self._acceptance.waits_for_query_null:  # decided when the queries' null is ready (_release)
            self._undecided[frame] = (score, distinct)
            accepted = False
        else:
            accepted = self._acceptance.accepts(confidence, score, distinct)
        return LoopResult(frame=frame, match=match, confidence=confidence, accepted=accepted, candidates=candidates)

    def _release(self, out: list[Message], ending: bool = False) -> list[Message]:
        """accept_query_null_wait: the answers given while the queries' null was not ready are held
        back (with every answer after them, so that answers keep their order) and decided at its
        threshold once it is; one that has waited ``accept_query_null_frames`` query frames (the
        null may never be ready on a short traversal), or when the traversal ends (``ending``), at
        the threshold then."""
        if not self._held_back and not self._undecided:
            return out
        kept: list[Message] = []
        for message in out:
            (self._held_back if isinstance(message, LoopResult) else kept).append(message)
        if ending or not self._acceptance.waits_for_query_null:
            due = len(self._held_back)
        else:  # only those that waited long enough
            oldest = self._query_frames - self.config.accept_query_null_frames
            due = next((k for k, r in enumerate(self._held_back) if self._query_position.get(r.frame, 0) > oldest),
                       len(self._held_back))
        released = []
        for result in self._held_back[:due]:
            if result.frame in self._undecided:
                result = replace(result, accepted=self._acceptance.accepts(result.confidence,
                                                                           *self._undecided.pop(result.frame)))
                self._n_waited += 1
            released.append(result)
        self._held_back = self._held_back[due:]
        return kept + released

    def _featureless(self, frame: int) -> LoopResult:
        self._count("featureless")
        return LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                          reason="featureless query frame (no edges to describe)")

    def _no_answer(self, frames: np.ndarray, reason: str) -> list[LoopResult]:
        self._counts["no_answer_frames"] = self._counts.get("no_answer_frames", 0) + len(frames)
        return [LoopResult(frame=int(f), match=-1, confidence=0.0, accepted=False, reason=reason) for f in frames]

    def _frames_of(self, places: list[int]) -> np.ndarray:
        return np.asarray([f for p in places for f in self._frames[p]], dtype=np.int64)

    def _count(self, key: str) -> None:
        self._counts[key] = self._counts.get(key, 0) + 1

    def _sequence_distances(self) -> int:
        """Descriptor distances computed after level 1 so far."""
        return 0

    def statistics(self) -> dict[str, float | int]:
        # the calibration's distances count in n_distances (the map counts its level-1 searches too)
        # and so do the queries' leave-the-answer-out null's (accept_query_null)
        calibration = sum(self._calibration_distances)
        null_search, null_sequences = self._query_null_distances
        search = (self._map.search_distances if self._map is not None else 0) - self._calibration_distances[0] \
            - null_search
        sequences = self._sequence_distances() - null_sequences
        stats: dict[str, float | int] = {
            "n_distances_calibration": calibration,
            "n_distances_query_null": null_search + null_sequences,
            "n_searches": self._counts.get("searches", 0),
            "n_query_sequences": self._n_iterations,
            "n_query_frames": self._query_frames,
            "n_distances": search + sequences + calibration + null_search + null_sequences,
            "n_distances_search": search,
            "n_distances_sequences": sequences,
            "accept_calibration_passes_run": self._calibration_seen[0],
            "accept_n_wrong_decisions": self._calibration_seen[1],
            "accept_answers_waited": self._n_waited,
        }
        for key in (*self.branch_keys, "map_too_small", "no_candidate", "featureless", "no_answer_frames"):
            stats[f"n_{key}"] = self._counts.get(key, 0)
        return {**stats, **self._acceptance.statistics()}
