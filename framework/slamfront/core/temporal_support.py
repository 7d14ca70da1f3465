"""Temporally supported confidence: how confident an answer is *and* how many of the answers
just before it agree with it along the route.

A right loop-closure answer is usually supported by its neighbours in time: consecutive query
frames answer consecutive map frames, in one direction (the route is being re-driven, forwards
or backwards). A wrong answer usually is not: the next frame's wrong answer lands elsewhere.
The same idea is in SeqSLAM's sequence matching (Milford & Wyeth 2012) and in the temporal
consistency check of Rodrigues 2019; here it is a score an operating point can threshold,
computed from answers already given (causal: no look-ahead).

The supported confidence of answer ``i`` (query frame ``f_i`` answered with map frame ``m_i``
at confidence ``c_i``): among the answers to the ``answers - 1`` frames before it, those that
*agree* with it are the ones on the same line through it, ``|(m_j - m_i) - s (f_j - f_i)| <=
tolerance`` for one direction ``s`` in {+1, -1}; together with ``i`` itself, their confidences'
``agree``-th largest is the supported confidence (0 when fewer than ``agree`` agree). With
``agree = answers / 2`` it reads: at least half of the last ``answers`` answers lie on one line
with this one, each at least this confident. The answer's own confidence is one of them but
need not be the smallest: a weak answer in a confident run is supported by its run.

The price is latency: a revisit's first ``agree - 1`` frames cannot be supported yet (their
answers are given, with their confidence, but not accepted).

A detector that answers a whole query *sequence* at once (one confidence for all its frames)
counts in sequence decisions instead (``per_step``/``steps``): each decision is one answer (a
representative query frame and the map frame it is aligned with), the window is its last
``answers`` decisions, and a decision is supported when earlier decisions continue it along
the route (the next query stretch answered at the next map stretch, in the same direction).

Not every answer is evidence of where the route goes: one placed *by* the answers before it (a
sequence rebuilt from the previous one and continued, as Rodrigues 2019's Alg. 3 does) lies on
their line by construction, right or wrong. ``supplies`` says which answers may support later
ones; an answer that may not is still supported by those that may (it inherits support, it
cannot lend it), so a chain that only repeats itself is not its own support.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from slamfront.core.errors import CoreError


def _check(answers: int, agree: int, tolerance: float) -> None:
    if answers < 1 or not 1 <= agree <= answers:
        raise CoreError(f"support needs 1 <= agree <= answers, got agree={agree}, answers={answers}")
    if tolerance < 0:
        raise CoreError(f"support tolerance must be >= 0, got {tolerance}")


def support_of_last(frames: np.ndarray, matches: np.ndarray, confidences: np.ndarray,
                    answers: int, agree: int, tolerance: float, steps: np.ndarray | None = None,
                    supplies: np.ndarray | None = None) -> float:
    """The supported confidence of the *last* answer of ``frames``/``matches``/``confidences``
    (answers in time order; a match < 0 is no answer and supports nothing). Only earlier answers
    fewer than ``answers`` frames before it count, or, given ``steps`` (each answer's count in
    time, e.g. a sequence decision's number), fewer than ``answers`` steps before it; given
    ``supplies`` (bool per answer), only earlier answers marked True support it."""
    _check(answers, agree, tolerance)
    f = np.asarray(frames, dtype=np.float64)
    m = np.asarray(matches, dtype=np.float64)
    c = np.nan_to_num(np.asarray(confidences, dtype=np.float64), nan=0.0)
    if len(f) == 0 or m[-1] < 0:
        return 0.0
    gap = f[-1] - f[:-1]
    back = gap if steps is None else np.asarray(steps, dtype=np.float64)[-1] - np.asarray(steps, dtype=np.float64)[:-1]
    earlier = (back > 0) & (back < answers) & (m[:-1] >= 0)
    if supplies is not None:
        earlier &= np.asarray(supplies, dtype=bool)[:-1]
    best = 0.0
    for direction in (1.0, -1.0):
        on_line = earlier & (np.abs((m[:-1] - m[-1]) + direction * gap) <= tolerance)
        values = np.sort(np.concatenate([[c[-1]], c[:-1][on_line]]))[::-1]
        if len(values) >= agree:
            best = max(best, float(values[agree - 1]))
    return best


def supported_confidence(frames: np.ndarray, matches: np.ndarray, confidences: np.ndarray,
                         answers: int, agree: int, tolerance: float, per_step: bool = False,
                         supplies: np.ndarray | None = None) -> np.ndarray:
    """(n,) the supported confidence of every answer (in time order) from the answers before it
    (:func:`support_of_last` of each prefix). ``per_step``: ``answers`` counts answers (e.g.
    sequence decisions, each one step), not query frames; ``supplies``: which answers may
    support later ones (None: all)."""
    _check(answers, agree, tolerance)
    f = np.asarray(frames)
    m = np.asarray(matches)
    c = np.asarray(confidences)
    steps = np.arange(len(f)) if per_step else None
    out = np.zeros(len(f))
    for i in range(len(f)):
        lo = max(0, i - answers + 1)
        out[i] = support_of_last(f[lo:i + 1], m[lo:i + 1], c[lo:i + 1], answers, agree, tolerance,
                                 steps=None if steps is None else steps[lo:i + 1],
                                 supplies=None if supplies is None else np.asarray(supplies)[lo:i + 1])
    return out


def contiguous_self_queries(n: int, window: int, most: int, run: int = 50) -> np.ndarray:
    """Positions of a traversal of ``n`` frames to search against the rest of itself when their
    answers' *support* is wanted: every frame when there are no more than ``most``, else
    ``most // run`` stretches of ``run`` consecutive frames, evenly spread (support is measured
    along consecutive answers, so an even thinning would change it). Empty when no frame has a
    frame more than ``window`` away."""
    if n <= window + 1:
        return np.empty(0, dtype=np.int64)
    if n <= most:
        return np.arange(n, dtype=np.int64)
    run = max(1, min(run, most))
    starts = np.linspace(0, n - run, max(1, most // run)).round().astype(np.int64)
    return np.unique((starts[:, None] + np.arange(run)[None, :]).ravel())


class SupportTracker:
    """:func:`support_of_last` online: the last ``answers`` answers are kept (``per_step``: each
    update is one step, e.g. one sequence decision; else ``answers`` counts query frames)."""

    def __init__(self, answers: int, agree: int, tolerance: float, per_step: bool = False) -> None:
        _check(answers, agree, tolerance)
        self._answers, self._agree, self._tolerance = answers, agree, tolerance
        self._per_step = per_step
        self._recent: deque[tuple[int, int, float, bool]] = deque(maxlen=answers)

    def update(self, frame: int, match: int, confidence: float, supplies: bool = True) -> float:
        """The supported confidence of this answer (``match`` < 0: no answer, 0); ``supplies``:
        whether it may support later answers."""
        self._recent.append((int(frame), int(match), float(confidence), bool(supplies)))
        f, m, c, s = (np.array(column) for column in zip(*self._recent, strict=True))
        steps = np.arange(len(f)) if self._per_step else None
        return support_of_last(f, m, c, self._answers, self._agree, self._tolerance, steps=steps, supplies=s)
