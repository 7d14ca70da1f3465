"""What every loop detector shares about its operating point: ``accept: auto`` (the default)
or a fixed confidence, the bookkeeping
of a calibration and the ``AcceptThreshold`` messages that log it (a shared message type,
:mod:`slamfront.messages`; the rule itself: :mod:`slamfront.core.operating_point`).

``accept: auto`` never reads query ground truth. Paired traversals: the detector answers
reference frames against the rest of the reference outside ``accept_exclusion_frames`` (every such
answer is wrong), before its first query. A stream: the answers to its first
``accept_calibration_frames`` frames (before any revisit; none of them is accepted) are the wrong
ones. The threshold: those wrong confidences' ``1 - false_accept_rate`` quantile.

A detector whose config is a :class:`SupportConfig` may instead threshold each answer's
*temporally supported* confidence (:mod:`slamfront.core.temporal_support`: the confidence that
at least half of its recent answers, agreeing with it along the route, reach), calibrated the
same way: the same support computed over the reference's own consecutive wrong answers. The
answers keep their confidence (what precision-recall curves rank); only ``accepted`` changes.
Or both (``accept_score: confidence_or_supported``, detectors that offer it): an answer is
accepted on its own confidence at the usual threshold, or on its supported confidence at that
score's calibrated threshold but never below a floor, the ``support_floor_quantile`` of the
reference's wrong answers' own confidences (support counts only from answers more confident
than most wrong ones). A detector that judges a sequence of answers at once may also hand
over its wrong decisions (one confidence each): the threshold then discounts the largest when
it is an outlier of the others (:func:`~slamfront.core.operating_point.outlier_discounted_threshold`).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from slamfront.core.operating_point import (
    outlier_discounted_threshold,
    query_null_threshold,
    query_shift_threshold,
    threshold_at_false_accept_rate,
)
from slamfront.core.temporal_support import SupportTracker, supported_confidence
from slamfront.messages import AcceptThreshold, Message
from slamfront.plugin import PluginConfig


class AcceptanceConfig(PluginConfig):
    """The operating point of a loop detector's confidence (every detector's config has these)."""

    legacy_accept_key: ClassVar[str | None] = None
    """An older name of a fixed ``accept`` (still read, as ``accept: <value>``)."""

    accept: Literal["auto"] | float = Field(
        "auto", description="operating point: answers at this confidence or more are accepted; auto: calibrated "
        "from wrong answers the detector has seen (the reference against itself, or a stream's first frames) at "
        "false_accept_rate, never from query ground truth"
    )
    false_accept_rate: float = Field(
        0.01, ge=0, lt=1, description="accept: auto: the share of wrong answers the threshold may let through "
        "(chosen on Nordland chunks and synthetic worlds, docs/loop_closure.md)"
    )
    accept_calibration_frames: int = Field(
        200, ge=1, description="accept: auto in a stream: answers to the first this many frames calibrate the "
        "threshold (no revisit may happen in them; none of them is accepted)"
    )
    accept_exclusion_frames: int = Field(
        50, ge=1, description="accept: auto with a reference: reference frames this close to a reference frame "
        "searched against the others are not wrong matches"
    )
    accept_query_null: bool = Field(
        True, description="accept: auto with a reference, detectors that support it: the threshold may move down "
        "to the same false_accept_rate of the queries' own leave-the-answer-out confidences (what the detector "
        "answers with the answered stretch of the map left out: wrong by construction, under the queries' "
        "appearance), once there are accept_query_null_frames of them; never above the reference's threshold"
    )
    accept_query_null_rule: Literal["quantile", "shift"] = Field(
        "quantile", description="accept_query_null: quantile: the threshold is the false_accept_rate quantile of "
        "the queries' null; shift: the reference's threshold moved by the queries' null's median minus the "
        "median of the reference's wrong answers (the reference's well-sampled tail, the queries' location: for "
        "detectors whose answers are judged a sequence at a time, where a few null values underestimate the tail)"
    )
    accept_query_null_frames: int = Field(
        50, ge=1, description="accept_query_null: query frames with a leave-the-answer-out confidence needed "
        "before it may move the threshold"
    )
    accept_query_null_wait: bool = Field(
        True, description="accept_query_null, detectors that support it: answers given before the queries' null "
        "is ready wait for it and are decided at its threshold (they come up to accept_query_null_frames query "
        "frames late; at the end of the traversal, at the threshold then), so the first query frames are judged "
        "as the rest are (on a 111-frame traversal they are a third of it); false: each decided at once, at the "
        "reference's threshold until the null is ready"
    )

    @field_validator("accept")
    @classmethod
    def _in_unit_interval(cls, value: Any) -> Any:
        if value != "auto" and not 0.0 <= float(value) <= 1.0:
            raise ValueError("accept must be auto or a confidence in [0, 1]")
        return value

    @model_validator(mode="before")
    @classmethod
    def _legacy_key(cls, data: Any) -> Any:
        key = cls.legacy_accept_key
        if isinstance(data, dict) and key is not None and key in data:
            if "accept" in data:
                raise ValueError(f"give `accept` or its older name `{key}`, not both")
            data = {("accept" if k == key else k): v for k, v in data.items()}
        return data


class SupportConfig(AcceptanceConfig):
    """An operating point that may threshold the temporally supported confidence
    (:mod:`slamfront.core.temporal_support`) instead of the answer's own."""

    accept_score: Literal["confidence", "supported_confidence"] = Field(
        "supported_confidence", description="accept: auto: the score thresholded; supported_confidence: the "
        "confidence that at least support_agree of the last support_answers answers reach while agreeing with "
        "this one along the route (the reference's wrong answers scored the same way calibrate it; answers keep "
        "their own confidence). A given accept always compares the answer's own confidence"
    )
    support_answers: int = Field(20, ge=1, description="supported_confidence: answers (query frames) looked back over, "
                                 "this one included")
    support_agree: int = Field(10, ge=1, description="supported_confidence: answers that must agree (this one "
                               "included); a revisit's first support_agree - 1 frames are not accepted")
    support_tolerance_frames: float = Field(
        1.0, ge=0, description="supported_confidence: how far (map frames) an earlier answer may lie from the "
        "line through this one (slope +1 or -1: one map frame per query frame) and still agree"
    )
    support_per: Literal["frame", "decision"] = Field(
        "frame", description="supported_confidence: what support_answers and support_agree count: query frames, "
        "or sequence decisions (detectors that answer a query sequence at once, one confidence for all its frames)"
    )
    support_floor_quantile: float = Field(
        0.75, ge=0, le=1, description="accept_score: confidence_or_supported (detectors that offer it): the "
        "supported confidence's threshold is at least this quantile of the own confidences of the reference's "
        "wrong answers"
    )

    @model_validator(mode="after")
    def _agree_within_answers(self) -> SupportConfig:
        if self.support_agree > self.support_answers:
            raise ValueError("support_agree must be at most support_answers")
        return self


def _finite(values: np.ndarray | list[float]) -> np.ndarray:
    """The finite ones of ``values``, as float64."""
    values = np.asarray(values, dtype=np.float64)
    return values[np.isfinite(values)]


class Acceptance:
    """One detector's operating point: fixed, or calibrated once from wrong answers.

    Until calibrated, nothing is accepted. :meth:`messages` hands out the
    ``AcceptThreshold`` once (the detector adds it to its output).
    """

    def __init__(self, config: AcceptanceConfig, detector: str) -> None:
        self._config = config
        self._detector = detector
        self.auto = config.accept == "auto"
        self.threshold: float | None = None if self.auto else float(config.accept)
        self.n_wrong = 0
        self._stream_wrong: list[float] = []
        self._null: list[float] = []  # the queries' leave-the-answer-out confidences (one per query frame)
        self.reference_threshold: float | None = None
        self._reference_median: float | None = None  # of the reference's wrong confidences (the shift rule)
        self._logged = float("nan")  # the threshold last logged
        self._outbox: list[Message] = []
        score_kind = str(getattr(config, "accept_score", "confidence"))
        self._support = (config if self.auto and isinstance(config, SupportConfig)
                         and score_kind in ("supported_confidence", "confidence_or_supported",
                                            "confidence_or_supported_or_distinct") else None)
        self.either = self._support is not None and score_kind.startswith("confidence_or_supported")
        """Accepted on the own confidence or on the supported one, each at its own threshold."""
        self.support_threshold: float | None = None
        """accept_score: confidence_or_supported: the supported confidence's threshold."""
        self.distinct = self.auto and score_kind.endswith("_distinct")
        """Also accepted on the answer's distinctiveness at its own threshold (``accept_score:
        ..._or_distinct``, detectors that offer it: :func:`~slamfront.core.operating_point.distinctiveness`)."""
        self.distinct_threshold: float | None = None
        self.distinct_floor = 0.0
        """The own confidence an answer accepted on its distinctiveness needs at least."""
        self.n_wrong_distinct = 0
        """How many wrong reference decisions the distinctiveness threshold was calibrated on."""
        self.undiscounted: float | None = None
        """The reference's threshold before an outlier decision was discounted (None: no decisions given)."""
        self.on_support = self._support is not None
        """accept: auto on the temporally supported confidence (a :class:`SupportConfig` asks for it)."""
        self._tracker = (None if self._support is None else SupportTracker(
            self._support.support_answers, self._support.support_agree, self._support.support_tolerance_frames,
            per_step=self._support.support_per == "decision"))
        if not self.auto:
            self._outbox.append(AcceptThreshold(detector, float(self.threshold), False, "given", 0,  # type: ignore[arg-type]
                                                float("nan"), float("nan")))

    @property
    def calibrated(self) -> bool:
        return self.threshold is not None

    def accepts(self, confidence: float, score: float | None = None, distinct: float | None = None) -> bool:
        """Whether an answer is accepted: ``confidence`` (or ``score``, what :meth:`score` gave,
        when given) at the threshold; with ``accept_score: confidence_or_supported`` the
        confidence at the threshold or ``score`` at the supported one; with ``..._or_distinct``
        also when ``distinct`` (the answer's distinctiveness) reaches its own threshold."""
        if self.threshold is None:
            return False
        if (self.distinct and distinct is not None and self.distinct_threshold is not None
                and distinct >= self.distinct_threshold and confidence >= self.distinct_floor):
            return True
        if self.either and score is not None and self.support_threshold is not None:
            return confidence >= self.threshold or score >= self.support_threshold
        return (confidence if score is None else score) >= self.threshold

    def score(self, frame: int, match: int, confidence: float, supplies: bool = True) -> float:
        """What the threshold is compared with for this answer (answers in time order): its
        confidence, or with ``accept_score: supported_confidence`` its supported confidence
        (``support_per: decision``: one call per sequence decision, ``match`` < 0 when it has
        no answer; ``supplies``: whether this answer may support later ones)."""
        if self._tracker is None or not self.on_support:
            return confidence
        return self._tracker.update(frame, match, confidence, supplies)

    def reference_scores(self, positions: np.ndarray, matches: np.ndarray, confidences: np.ndarray,
                         supplies: np.ndarray | None = None) -> np.ndarray:
        """:meth:`score` of the reference's answers to itself (positions in time order), to calibrate on."""
        c = self._support
        if c is None or not self.on_support:
            return np.asarray(confidences, dtype=np.float64)
        return supported_confidence(positions, matches, confidences, c.support_answers, c.support_agree,
                                    c.support_tolerance_frames, per_step=c.support_per == "decision",
                                    supplies=supplies)

    def calibrate_reference(self, own: list[float], scored: list[float],
                            decisions: list[float] | None = None) -> float:
        """Calibrate on the reference's wrong answers: their own confidences ``own`` and what
        :meth:`score` gave them, ``scored`` (the same answers, in the same order). With
        ``accept_score: confidence_or_supported`` the threshold is on ``own`` and the supported
        one on ``scored``, never below the floor (``support_floor_quantile`` of ``own``).
        ``decisions``: the same wrong answers' confidences, one per decision (a detector that
        judges a sequence at once), when the own threshold is to discount an outlier among them
        (:func:`outlier_discounted_threshold`)."""
        if not self.either:
            return self.calibrate(scored, "reference", None if self.on_support else decisions)
        values = _finite(own)
        floor = float(np.quantile(values, self._support.support_floor_quantile)) if len(values) else 1.0  # type: ignore[union-attr]
        self.support_threshold = max(floor, threshold_at_false_accept_rate(
            np.asarray(scored, dtype=np.float64), self._config.false_accept_rate))
        return self.calibrate(own, "reference", decisions)

    def calibrate_distinct(self, wrong: list[float], own: list[float]) -> float:
        """``accept_score: ..._or_distinct``: the distinctiveness threshold, at ``false_accept_rate``
        of the reference's wrong decisions' distinctiveness ``wrong`` (one value per decision; 1,
        accepting nothing on it, when there is none), and the floor of the own confidence an answer
        accepted on it needs: the ``distinct_floor_quantile`` of the reference's wrong answers' own
        confidences ``own`` (a detector's config that offers the score has it; 0: no floor)."""
        values = _finite(wrong)
        self.n_wrong_distinct = len(values)
        self.distinct_threshold = threshold_at_false_accept_rate(values, self._config.false_accept_rate)
        confidences = _finite(own)
        quantile = float(getattr(self._config, "distinct_floor_quantile", 0.0))
        self.distinct_floor = float(np.quantile(confidences, quantile)) if quantile > 0 and len(confidences) else 0.0
        return self.distinct_threshold

    def calibrate(self, wrong: np.ndarray | list[float], source: str, decisions: list[float] | None = None) -> float:
        """Set the threshold from the confidences of answers known to be wrong (``decisions``:
        the same, one per decision, to discount an outlier among them)."""
        values = _finite(wrong)
        rate = self._config.false_accept_rate
        self.threshold = threshold_at_false_accept_rate(values, rate)
        if decisions is not None:
            self.undiscounted = self.threshold
            self.threshold = outlier_discounted_threshold(self.threshold, decisions, rate)
        self.n_wrong = len(values)
        if source == "reference":
            self.reference_threshold = self._logged = self.threshold
            self._reference_median = float(np.median(values)) if len(values) else None
        self._outbox.append(AcceptThreshold(
            self._detector, self.threshold, True, source, len(values), rate,
            float(values.max()) if len(values) else float("nan"),
        ))
        return self.threshold

    @property
    def wants_query_null(self) -> bool:
        """Whether :meth:`query_null` is used (a detector may skip the extra search otherwise)."""
        return (self.auto and self._config.accept_query_null and self.reference_threshold is not None
                and not self.on_support)  # the null is of answers' own confidences

    @property
    def waits_for_query_null(self) -> bool:
        """Whether an answer given now is to wait for the queries' null (``accept_query_null_wait``):
        the null is wanted and has fewer than ``accept_query_null_frames`` values yet."""
        return (self.wants_query_null and self._config.accept_query_null_wait
                and len(self._null) < self._config.accept_query_null_frames)

    def query_null(self, confidence: float, frames: int = 1) -> None:
        """A query's leave-the-answer-out confidence (the detector's answer with the answered
        stretch of the map left out: wrong by construction), for ``frames`` query frames.
        With ``accept_query_null`` and a calibrated reference threshold, once there are
        ``accept_query_null_frames`` of them the threshold is the smaller of the reference's and
        the same ``false_accept_rate`` quantile of these (:func:`query_null_threshold`), or with
        ``accept_query_null_rule: shift`` the reference's moved down by how much lower their median
        is (:func:`query_shift_threshold`): it moves down only as far as wrong answers under the
        queries' own appearance allow."""
        if not self.wants_query_null or not np.isfinite(confidence):
            return
        self._null.extend([float(confidence)] * frames)
        if len(self._null) < self._config.accept_query_null_frames:
            return
        if self._config.accept_query_null_rule == "shift":
            if self._reference_median is None:
                return
            threshold = query_shift_threshold(self.reference_threshold, self._reference_median, self._null)
        else:
            threshold = query_null_threshold(self.reference_threshold, self._null, self._config.false_accept_rate)
        self.threshold = threshold
        if abs(threshold - self._logged) > 0.005:  # log it when it first moves, and each time it moves again
            self._logged = threshold
            self._outbox.append(AcceptThreshold(
                self._detector, float(self.threshold), True, "queries", len(self._null),  # type: ignore[arg-type]
                self._config.false_accept_rate, float(max(self._null)),
            ))

    def stream_answer(self, position: int, confidence: float) -> bool:
        """A stream's answer to its ``position``-th frame (0-based): gathered as a wrong one while
        in the first ``accept_calibration_frames``, the threshold set at the first answer after them.
        Returns whether it is accepted. A stream's threshold is on the answers' own confidence
        (so a detector asking for the supported one, or either, reports that it is not used)."""
        self.on_support = self.either = self.distinct = False
        if self.calibrated:
            return self.accepts(confidence)
        if position < self._config.accept_calibration_frames:
            self._stream_wrong.append(confidence)
            return False
        self.calibrate(self._stream_wrong, "stream")
        return self.accepts(confidence)

    def finish(self) -> None:
        """The run ended: a stream shorter than its calibration still logs what it would use."""
        if not self.calibrated:
            self.calibrate(self._stream_wrong, "stream")

    def messages(self) -> list[Message]:
        out, self._outbox = self._outbox, []
        return out

    def statistics(self) -> dict[str, float | int]:
        nan = float("nan")
        return {"accept_threshold": nan if self.threshold is None else self.threshold,
                "accept_auto": int(self.auto), "accept_n_wrong": self.n_wrong,
                "accept_threshold_reference": nan if self.reference_threshold is None else self.reference_threshold,
                "accept_n_query_null": len(self._null),
                **({"accept_threshold_supported": nan if self.support_threshold is None else self.support_threshold}
                   if self.either else {}),
                **({"accept_threshold_undiscounted": self.undiscounted} if self.undiscounted is not None else {}),
                **({"accept_threshold_distinct": nan if self.distinct_threshold is None else self.distinct_threshold,
                    "accept_distinct_floor": self.distinct_floor,
                    "accept_n_wrong_distinct": self.n_wrong_distinct} if self.distinct else {}),
                **({"accept_on_supported_confidence": int(self.on_support)}
                   if isinstance(self._config, SupportConfig) else {})}
