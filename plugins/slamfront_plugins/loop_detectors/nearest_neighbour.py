"""The ``nearest_neighbour`` loop detector: brute-force search over all earlier frames."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
from pydantic import Field

from slamfront import LoopDetector, Plugin, StageInputs
from slamfront.acceptance import Acceptance, SupportConfig
from slamfront.core.buffers import GrowingRows
from slamfront.core.distances import pairwise, rowwise, smallest, to_one
from slamfront.core.operating_point import (
    exclusion_masked,
    exclusion_window,
    moving,
    self_queries,
    travelled,
    uniqueness_confidence,
)
from slamfront.core.temporal_support import contiguous_self_queries
from slamfront.messages import LoopResult, Message
from slamfront.plugin import global_features, require_global_descriptor


class NearestNeighbour(LoopDetector):
    """Single-image baseline: each query's best match is its nearest earlier frame.

    Reference frames are stored; query frames are searched against them (and stream
    frames against all frames older than ``exclude_recent``). The confidence is a
    uniqueness score, ``1 - d_best / d_second``, where ``d_second`` is the best distance
    outside ``uniqueness_window`` frames of the best match, so a match that is much
    better than anywhere else is trusted more. ``accept`` is the operating point: by default
    calibrated on the reference searched against itself outside ``accept_exclusion_frames`` (or on
    a stream's first ``accept_calibration_frames``), see :mod:`slamfront.acceptance`. With paired
    traversals ``accept: auto`` thresholds the *supported* confidence
    (:mod:`slamfront.core.temporal_support`): a single image's uniqueness drops under an appearance
    change for right and wrong answers alike, but right answers keep agreeing with their
    neighbours along the route. A stream keeps the answer's own confidence.
    """

    name = "nearest_neighbour"
    requires = ("descriptor",)

    class Config(SupportConfig):
        legacy_accept_key = "threshold"

        false_accept_rate: float = Field(
            0.0, ge=0, lt=1, description="accept: auto: the share of wrong answers the threshold may let through; "
            "0: above every wrong answer on the reference (at 0.01 a chunk of Nordland, 1127-1772, let wrong answers "
            "through: precision 0.915)"
        )

        accept_query_null: bool = Field(
            False, description="accept: auto with accept_score: confidence: let the queries' leave-the-answer-out "
            "null move the threshold down (acceptance.py); not used on the supported confidence, which replaced it "
            "as the default (docs/loop_closure.md)"
        )
        accept_query_null_rule: Literal["quantile", "shift"] = Field(
            "shift", description="accept_query_null (acceptance.py): shift; the quantile rule (the largest null "
            "value at false_accept_rate 0) let wrong answers through on Nordland chunks (docs/loop_closure.md)"
        )
        support_answers: int = Field(
            40, ge=1, description="supported_confidence: answers (query frames) looked back over, this one "
            "included (40, not the shared 20: a repeated stretch of the reference, about 20 frames of one synthetic "
            "street, set the 20-answer threshold above what right answers at night reach; docs/loop_closure.md)"
        )
        support_agree: int = Field(20, ge=1, description="supported_confidence: answers that must agree (this one "
                                   "included); a revisit's first support_agree - 1 frames are not accepted")
        accept_exclusion_pace: bool = Field(
            True, description="accept: auto on the supported confidence: measure accept_exclusion_frames along "
            "the reference's own pace (core/operating_point.py: travelled; a step whose frames differ less than "
            "the median step's counts as that fraction of a frame), so a reference crawling through one place "
            "for longer than the window does not count its own revisits of that place as wrong answers"
        )
        uniqueness_window: int = Field(10, ge=0, description="frames around the best match ignored for d_second")
        exclude_recent: int = Field(50, ge=0, description="stream mode: skip this many most recent frames")
        candidates: int = Field(10, ge=1, description="ranked candidates reported per query (recall@K)")

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._vectors: GrowingRows | None = None
        self._frames: list[int] = []
        self._n_reference = 0
        self._n_query = 0
        self._n_searches = 0
        self._n_distances = 0
        self._metric = "l2"
        self._acceptance = Acceptance(self.config, self.name)
        self._n_calibration_distances = 0

    def check(self, stages: Mapping[str, Plugin]) -> None:
        require_global_descriptor(stages)

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        features = global_features(inputs)
        frame = inputs.frame
        self._metric = features.metric
        if self._vectors is None:
            self._vectors = GrowingRows(len(features.vector))
        result: list[Message] = []
        if frame.traversal == "query" and not self._acceptance.calibrated:
            self._calibrate_on_reference()
        if frame.traversal in ("query", "stream"):
            answer = self._search(frame.index, features.vector, frame.traversal == "stream")
            if answer.match >= 0:
                accepted = (self._acceptance.stream_answer(self._n_query, answer.confidence)
                            if frame.traversal == "stream" else
                            self._acceptance.accepts(self._acceptance.score(frame.index, answer.match,
                                                                            answer.confidence)))
                answer = LoopResult(frame=answer.frame, match=answer.match, confidence=answer.confidence,
                                    accepted=accepted, candidates=answer.candidates)
            result.append(answer)
            self._n_query += 1
        if frame.traversal in ("reference", "stream"):
            self._vectors.append(features.vector)
            self._frames.append(frame.index)
            self._n_reference += 1
        return [*self._acceptance.messages(), *result]

    def finish(self) -> Sequence[Message]:
        self._acceptance.finish()
        return self._acceptance.messages()

    def _calibrate_on_reference(self) -> None:
        """Every reference frame's best match among the reference frames more than
        ``accept_exclusion_frames`` away is wrong: its confidences (or their support along
        consecutive reference frames) calibrate the threshold."""
        n = 0 if self._vectors is None else len(self._frames)
        window = exclusion_window(n, self.config.accept_exclusion_frames)
        queries = (contiguous_self_queries if self._acceptance.on_support else self_queries)(n, window, 500)
        if len(queries) == 0:
            self._acceptance.calibrate([], "reference")
            return
        rows = self._vectors.view[:n]  # type: ignore[union-attr]
        queries = queries[np.any(rows[queries] != 0, axis=1)]  # featureless frames get no answer
        distances = pairwise(rows, rows[queries], self._metric)  # type: ignore[arg-type]
        self._n_calibration_distances = distances.size
        along = np.arange(n, dtype=np.float64)
        if self._acceptance.on_support and self.config.accept_exclusion_pace:
            along = travelled(rowwise(rows[1:], rows[:-1], self._metric))  # type: ignore[arg-type]
            self._n_calibration_distances += n - 1
        masked = exclusion_masked(distances, along, along[queries], window)
        best, confidence = uniqueness_confidence(masked, self.config.uniqueness_window)
        scores = self._acceptance.reference_scores(queries, best, confidence)
        self._acceptance.calibrate(scores[moving(distances, np.arange(n), queries)], "reference")

    def _search(self, frame: int, vector: np.ndarray, stream: bool) -> LoopResult:
        if not np.any(vector):  # featureless (a black or blank frame): equally near every other one
            return LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False,
                              reason="featureless query frame (all-zero descriptor)")
        usable = len(self._frames) - (self.config.exclude_recent if stream else 0)
        if self._vectors is None or usable < 1:
            return LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False, reason="map too small")
        self._n_searches += 1
        self._n_distances += usable
        distances = to_one(vector, self._vectors.view[:usable], self._metric)  # type: ignore[arg-type]
        order = smallest(distances, self.config.candidates)  # the stable sort's first ranks, without sorting all
        best = int(order[0])
        confidence = self._uniqueness(distances)  # its best is order[0]: both take the first smallest
        if not stream and self._acceptance.wants_query_null:
            self._leave_answer_out(distances, best)
        frames = np.asarray(self._frames[:usable], dtype=np.int64)
        return LoopResult(
            frame=frame,
            match=int(frames[best]),
            confidence=confidence,
            accepted=False,  # decided by the operating point
            candidates=frames[order[: self.config.candidates]],
        )

    def _uniqueness(self, distances: np.ndarray) -> float:
        """``1 - d_best / d_second`` of one query (core/operating_point.py: ``uniqueness_confidence``, the
        rule the calibration applies to the reference's own answers)."""
        return float(uniqueness_confidence(distances[:, None], self.config.uniqueness_window)[1][0])

    def _leave_answer_out(self, distances: np.ndarray, best: int) -> None:
        """accept: auto's null under the queries' appearance (:meth:`Acceptance.query_null`): the
        best match outside the exclusion window (``accept_exclusion_frames``) around the answer, and
        its confidence by the same uniqueness rule; wrong by construction. No extra distance."""
        window = exclusion_window(len(self._frames), self.config.accept_exclusion_frames)
        masked = np.where(np.abs(np.arange(len(distances)) - best) <= window, np.inf, distances)
        if not np.isfinite(masked).any():
            return
        self._acceptance.query_null(self._uniqueness(masked))

    def statistics(self) -> dict[str, float | int]:
        return {
            "n_searches": self._n_searches,
            "n_places_reference": self._n_reference,
            "n_places_query": self._n_query,
            "n_distances": self._n_distances + self._n_calibration_distances,
            "n_distances_calibration": self._n_calibration_distances,
            **self._acceptance.statistics(),
        }
