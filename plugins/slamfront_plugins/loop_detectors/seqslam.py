"""The ``seqslam`` and ``seqslam_fast`` loop detectors (OpenSeqSLAM and a Fast-SeqSLAM variant).

Both compare a query traversal with a reference traversal (references first, as in the
Rodrigues 2019's protocol) through :mod:`slamfront.core.seqslam`. ``seqslam`` fills the whole
difference matrix; ``seqslam_fast`` only the k nearest references of each query, and
scores only the trajectories that pass through them.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import LoopDetector, Plugin, PluginError, StageInputs
from slamfront.acceptance import Acceptance, AcceptanceConfig
from slamfront.core.buffers import GrowingRows
from slamfront.core.distances import smallest
from slamfront.core.operating_point import exclusion_window
from slamfront.core.seqslam import (
    best_match,
    difference_columns,
    enhance_contrast,
    enhanced_lower_bound,
    path_scores_block,
    sequence_scores_block,
    trajectory_offsets,
)
from slamfront.messages import Features, LoopResult, Message

CALIBRATION_BLOCKS = 8
"""accept: auto: the reference is searched against itself in this many blocks of queries ..."""
CALIBRATION_BLOCK_QUERIES = 40
"""... of this many answered queries each, spread evenly over it."""


class SeqSlamConfig(AcceptanceConfig):
    """Parameters shared by both variants; defaults are OpenSeqSLAM 2013's (but ``accept``)."""

    legacy_accept_key = "threshold"

    ds: int = Field(10, ge=2, description="sequence length (OpenSeqSLAM 10, Rodrigues 2019: 40); even")
    search: Literal["lines", "paths"] = Field(
        "lines", description="lines (default, as OpenSeqSLAM): straight trajectories at vmin..vmax, the query running the "
        "reference forwards at nearly its pace; paths: paths of straight segments at any speed path_low..path_high "
        "each, forwards or (reverse) backwards, found by dynamic programming (a query at another or changing pace, "
        "or driven the other way), answered at the query's own column; opt-in, not in the papers: on the whole Nordland "
        "route it gives R@100%P 0.745 against the lines' 0.763"
    )
    vmin: float = Field(0.8, gt=0, description="search lines: slowest trajectory, reference frames per query frame")
    vmax: float = Field(1.2, gt=0, description="search lines: fastest trajectory")
    path_low: float = Field(0.5, gt=0, description="search paths: slowest segment, reference frames per query frame")
    path_high: float = Field(2.0, gt=0, description="search paths: fastest segment")
    path_segment: int = Field(
        20, ge=1, description="search paths: query frames per straight segment (20 of ds 40: a path bends once "
        "either side of the query; 10 lost more on the unchanged control of Nordland 2900-3499)"
    )
    reverse: bool = Field(True, description="search paths: backward paths too (the reference driven the other way)")
    contrast_window: int = Field(10, ge=2, description="R: rows of the local contrast enhancement window")
    rwindow: int = Field(10, ge=0, description="rows around the best match excluded for the second best")
    mode: Literal["batch", "online"] = Field(
        "batch", description="batch: all queries, then match; online: answer each query ds/2 frames later"
    )
    score_offset: Literal["global_min", "bound"] = Field(
        "global_min",
        description="shift making scores >= 0: the matrix minimum (OpenSeqSLAM, batch only) or its lower bound",
    )
    candidates: int = Field(10, ge=1, description="ranked candidates reported per query (recall@K)")
    chunk: int = Field(256, ge=1, description="queries per block in batch mode (memory: references x chunk)")
    cache_mb: float = Field(
        512, ge=0,
        description="batch with global_min: keep the difference columns of the first pass (which finds the "
        "minimum) for the second when they fit in this many MB, instead of computing them twice",
    )

    @model_validator(mode="after")
    def _consistent(self) -> SeqSlamConfig:
        if self.ds % 2:
            raise ValueError(f"ds must be even (OpenSeqSLAM rounds {self.ds} up to {self.ds + 1})")
        if self.vmin > self.vmax:
            raise ValueError("vmin must not exceed vmax")
        if self.path_low > self.path_high:
            raise ValueError("path_low must not exceed path_high")
        if self.mode == "online" and self.score_offset == "global_min":
            raise ValueError("online mode cannot know the global minimum: use score_offset: bound")
        return self


class _SequenceDetector(LoopDetector):
    """What both variants share: buffering, windows of query columns, answers."""

    requires = ("descriptor",)
    config: SeqSlamConfig

    def __init__(self, config: SeqSlamConfig | None = None) -> None:
        super().__init__(config)
        c = self.config
        self._offsets = trajectory_offsets(c.ds, c.vmin, c.vmax)
        # lines start ds/2 before the answered query (OpenSeqSLAM); paths are scored at its own column
        self._answered_at = c.ds // 2 if c.search == "lines" else 0
        self._references: GrowingRows | None = None
        self._reference_frames: list[int] = []
        self._reference_index = np.empty(0, dtype=np.int64)
        """``_reference_frames`` as an array, rebuilt only when references were added."""
        self._query_frames: list[int] = []
        self._query_vectors: list[np.ndarray] = []
        self._window: deque[tuple[int, np.ndarray, np.ndarray | None]] = deque(maxlen=c.ds + 1)
        self._pending: deque[int] = deque()
        self._n_searches = 0
        self._acceptance = Acceptance(self.config, self.name)
        self._calibration_distances = 0

    def check(self, stages: Mapping[str, Plugin]) -> None:
        if not getattr(stages["descriptor"], "produces_global", False):
            raise PluginError(f"needs a global descriptor; {stages['descriptor'].name!r} produces none")

    # -- per-variant pieces ----------------------------------------------------------------

    def _columns(self, queries: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        """Enhanced difference columns (R, q) of some queries, and the rows worth scoring
        for each (None: all rows)."""
        raise NotImplementedError

    def _self_columns(self, positions: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        """As :meth:`_columns` for reference frames (by position) searched against the
        reference, with the rows within ``accept_exclusion_frames`` of each out of reach."""
        raise NotImplementedError

    def _band(self, positions: np.ndarray) -> np.ndarray:
        """(R, q) bool: reference rows within ``accept_exclusion_frames`` of each reference column."""
        assert self._references is not None
        rows = np.arange(len(self._references))
        window = exclusion_window(len(rows), self.config.accept_exclusion_frames)
        return np.abs(rows[:, None] - positions[None, :]) <= window

    # -- the operating point -------------------------------------------------------------------

    def _calibrate_on_reference(self) -> None:
        """accept: auto: answer reference frames from the reference outside ``accept_exclusion_frames``
        (every such answer is wrong), through the same difference matrix, enhancement and
        sequence search as the queries; their confidences set the threshold."""
        c = self.config
        half = c.ds // 2
        n = 0 if self._references is None else len(self._references)
        wrong: list[float] = []
        lo, hi = half, n - half  # reference positions with a full window
        if self._too_few_references() is None and hi - lo > 0 and n > 2 * exclusion_window(n, c.accept_exclusion_frames) + c.ds:
            size = min(CALIBRATION_BLOCK_QUERIES, hi - lo)
            starts = np.unique(np.linspace(lo, hi - size, CALIBRATION_BLOCKS).round().astype(np.int64))
            blocks = [self._self_columns(np.arange(start - half, start + size + half)) for start in starts]
            self._calibration_distances = n * sum(columns.shape[1] for columns, _ in blocks)
            offset = enhanced_lower_bound(c.contrast_window)
            if c.score_offset == "global_min":
                offset = min(float(columns.min()) for columns, _ in blocks)
            for columns, rows in blocks:
                shifted = columns.astype(np.float64) - offset
                windows = [self._start_rows(rows[k : k + c.ds + 1], len(shifted)) for k in range(size)]
                for scores in self._scores(shifted, windows):  # the queries' own search (lines or paths)
                    found = best_match(scores, 2 * self._answered_at, c.rwindow)
                    if found is not None:
                        wrong.append(float(np.clip(1.0 - found.ratio, 0.0, 1.0)))
        self._acceptance.calibrate(wrong, "reference")

    # -- streaming ---------------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[LoopResult]:
        features: Features = inputs.one("descriptor", Features)
        frame = inputs.frame
        if features.vector is None:
            raise PluginError(f"descriptor gave no global vector for frame {frame.index}")
        if frame.traversal == "stream":
            raise PluginError(
                f"{self.name} matches a query traversal against a reference traversal; "
                "this source yields one stream (use a paired source)"
            )
        if frame.traversal == "reference":
            if self._query_frames:
                raise PluginError(f"reference frame {frame.index} arrived after the queries started")
            if self._references is None:
                self._references = GrowingRows(len(features.vector), features.vector.dtype)
            elif len(features.vector) != self._references.view.shape[1]:
                raise PluginError(
                    f"frame {frame.index}: descriptor length {len(features.vector)} differs from "
                    f"{self._references.view.shape[1]} (images of different sizes?)"
                )
            self._references.append(features.vector)
            self._reference_frames.append(frame.index)
            return []
        if self._references is not None and len(features.vector) != self._references.view.shape[1]:
            raise PluginError(
                f"frame {frame.index}: query descriptor length {len(features.vector)} differs from the "
                f"references' {self._references.view.shape[1]} (images of different sizes?)"
            )
        if not self._query_frames and self._acceptance.auto:
            self._calibrate_on_reference()
        self._query_frames.append(frame.index)
        if self.config.mode == "batch":
            self._query_vectors.append(features.vector)
            return []
        return self._with_messages(self._online(frame.index, features.vector))

    def _as_reference_type(self, vectors: np.ndarray) -> np.ndarray:
        assert self._references is not None
        return vectors.astype(self._references.view.dtype, copy=False)

    def _no_answer(self, frame: int, reason: str) -> LoopResult:
        return LoopResult(frame=frame, match=-1, confidence=0.0, accepted=False, reason=reason)

    def _too_few_references(self) -> str | None:
        reach = int(self._offsets.max())
        n = 0 if self._references is None else len(self._references)
        if n < max(reach + 1, 2):
            return f"the reference has {n} frames; a trajectory needs {reach + 1}"
        return None

    def _online(self, frame: int, vector: np.ndarray) -> list[LoopResult]:
        half = self.config.ds // 2
        problem = self._too_few_references()
        if problem:
            return [self._no_answer(frame, problem)]
        column, rows = self._columns(self._as_reference_type(vector[None, :]))
        self._window.append((frame, column[:, 0], rows[0]))
        if len(self._query_frames) <= half:
            return [self._no_answer(frame, f"among the first ds/2 = {half} queries")]
        self._pending.append(frame)
        if len(self._window) < self.config.ds + 1:
            return []
        middle = self._pending.popleft()
        columns = np.stack([c for _, c, _ in self._window], axis=1)
        shifted = columns.astype(np.float64) - enhanced_lower_bound(self.config.contrast_window)
        starts = self._start_rows([r for _, _, r in self._window], len(shifted))
        return [self._answer(middle, self._scores(shifted, [starts])[0])]

    def _with_messages(self, out: Sequence[LoopResult]) -> list[Message]:
        return [*self._acceptance.messages(), *out]

    def finish(self) -> Sequence[Message]:
        if self._acceptance.auto and not self._acceptance.calibrated:
            self._calibrate_on_reference()
        if self.config.mode == "online":
            half = self.config.ds // 2
            return self._with_messages([self._no_answer(f, f"among the last ds/2 = {half} queries")
                                         for f in self._pending])
        return self._with_messages(self._batch())

    def _batch(self) -> list[LoopResult]:
        c = self.config
        half = c.ds // 2
        frames = self._query_frames
        problem = self._too_few_references()
        if problem or len(frames) < c.ds + 1:
            reason = problem or f"{len(frames)} queries are fewer than a sequence of ds + 1 = {c.ds + 1}"
            return [self._no_answer(f, reason) for f in frames]
        queries = self._as_reference_type(np.stack(self._query_vectors))
        # blocks of answered queries, each with the ds/2 queries either side its windows need
        blocks = [(start, min(start + c.chunk, len(frames) - half)) for start in range(half, len(frames) - half, c.chunk)]
        kept: dict[int, tuple[np.ndarray, list[np.ndarray | None]]] = {}
        offset = enhanced_lower_bound(c.contrast_window)
        if c.score_offset == "global_min":
            # the blocks cover every query, and a query's column does not depend on its block
            fits = len(self._references) * (len(frames) + len(blocks) * c.ds) * 4 <= c.cache_mb * 2**20
            offset = np.inf
            for k, (start, stop) in enumerate(blocks):
                block = self._columns(queries[start - half : stop + half])
                offset = min(offset, float(block[0].min()))
                if fits:
                    kept[k] = block
        results = [self._no_answer(f, f"among the first ds/2 = {half} queries") for f in frames[:half]]
        for k, (start, stop) in enumerate(blocks):
            columns, rows = kept.pop(k, None) or self._columns(queries[start - half : stop + half])
            shifted = columns.astype(np.float64) - offset  # once per block, not once per window
            starts = [self._start_rows(rows[lo : lo + c.ds + 1], len(shifted)) for lo in range(stop - start)]
            scores = self._scores(shifted, starts)  # every query of the block at once
            results += [self._answer(frames[n], scores[n - start]) for n in range(start, stop)]
        results += [self._no_answer(f, f"among the last ds/2 = {half} queries") for f in frames[len(frames) - half :]]
        self._query_vectors.clear()
        return results

    def _scores(self, shifted: np.ndarray, starts: list[np.ndarray | None]) -> np.ndarray:
        """(Q, R) cost per query of a block and reference row (:func:`sequence_scores_block`'s
        start rows for lines; :func:`path_scores_block`'s middle rows, every row, for paths)."""
        c = self.config
        if c.search == "lines":
            return sequence_scores_block(shifted, self._offsets, starts)
        return path_scores_block(shifted, c.ds, c.path_segment, c.path_low, c.path_high, c.reverse)

    def _answer(self, frame: int, scores: np.ndarray) -> LoopResult:
        """Match one query from its (R,) best trajectory costs per start row (computed on
        its window of enhanced columns in float64, shifted so that every score is >= 0)."""
        self._n_searches += 1
        found = best_match(scores, 2 * self._answered_at, self.config.rwindow)
        if found is None:
            return self._no_answer(frame, "no trajectory stays inside the reference")
        confidence = float(np.clip(1.0 - found.ratio, 0.0, 1.0))
        ranked = smallest(scores, self.config.candidates)
        ranked = ranked[np.isfinite(scores[ranked])]
        if len(self._reference_index) != len(self._reference_frames):
            self._reference_index = np.asarray(self._reference_frames, dtype=np.int64)
        reference_frames = self._reference_index
        return LoopResult(
            frame=frame,
            match=int(reference_frames[found.reference]),
            confidence=confidence,
            accepted=self._acceptance.accepts(confidence),
            candidates=reference_frames[ranked + self._answered_at],
        )

    def _start_rows(self, rows: list[np.ndarray | None], n_ref: int) -> np.ndarray | None:
        """Start rows whose trajectories pass through a kept entry (None: every row).

        ``window`` anchors: a kept entry of any query of the window; ``middle``: of the
        query being answered only (Fast-SeqSLAM's anchoring on the current image).
        """
        if any(r is None for r in rows):
            return None
        columns = [len(rows) // 2] if getattr(self.config, "anchor", "window") == "middle" else range(len(rows))
        wanted = np.zeros(n_ref, dtype=bool)
        for k in columns:
            starts = (rows[k][:, None] - self._offsets[:, k][None, :]).ravel()  # type: ignore[index]
            wanted[starts[(starts >= 0) & (starts < n_ref)]] = True
        return np.flatnonzero(wanted)

    def _distance_count(self) -> int:
        """Descriptor distances the detector needs: every entry of the difference matrix."""
        return len(self._reference_frames) * len(self._query_frames)

    def statistics(self) -> dict[str, float | int]:
        return {
            "n_searches": self._n_searches,
            "n_places_reference": len(self._reference_frames),
            "n_places_query": len(self._query_frames),
            "n_distances": self._distance_count() + self._calibration_distances,
            "n_distances_calibration": self._calibration_distances,
            **self._acceptance.statistics(),
        }


class SeqSlam(_SequenceDetector):
    """SeqSLAM as OpenSeqSLAM (Suenderhauf et al. 2013): sequences of thumbnails, full difference matrix.

    The difference matrix (mean absolute difference of the ``seqslam_thumbnail``
    vectors), local contrast enhancement along the reference axis, straight-line sequence
    search over ``ds`` + 1 queries at velocities ``vmin`` .. ``vmax``, and a uniqueness
    ratio (best / second best outside ``rwindow``). The first and last ``ds``/2 queries get
    an explicit no-answer, as in OpenSeqSLAM. Confidence = 1 - ratio.
    """

    name = "seqslam"

    class Config(SeqSlamConfig):
        pass

    def _columns(self, queries: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        assert self._references is not None
        differences = difference_columns(self._references.view, queries)
        return enhance_contrast(differences, self.config.contrast_window), [None] * len(queries)

    def _self_columns(self, positions: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        assert self._references is not None
        references = self._references.view
        enhanced = enhance_contrast(difference_columns(references, references[positions]), self.config.contrast_window)
        # the band (the frame itself and its neighbours) is enhanced as in any column, then out of reach
        return np.where(self._band(positions), enhanced.max(), enhanced), [None] * len(positions)


class SeqSlamFast(_SequenceDetector):
    """Fast-SeqSLAM idea (Siam & Zhang 2017): only each query's k nearest references count.

    The difference matrix keeps, per query, its ``k`` nearest references (exact, by the
    same mean absolute difference, which still compares every reference; or approximate,
    by a FAISS HNSW index on L2, which does not); the other entries take the column's
    largest kept value. Contrast enhancement runs as in ``seqslam``; the sequence search
    scores only the trajectories through a kept entry (of any query of the window, or,
    with ``anchor: middle``, of the answered query only).
    """

    name = "seqslam_fast"

    class Config(SeqSlamConfig):
        k: int = Field(20, ge=1, description="nearest references kept per query")
        knn: Literal["exact", "hnsw"] = Field(
            "exact", description="exact L1 neighbours, or approximate ones from a FAISS HNSW index (L2)"
        )
        anchor: Literal["window", "middle"] = Field(
            "window",
            description="score trajectories through a neighbour of any query of the window, or of the "
            "answered query only (Fast-SeqSLAM's anchoring; fastest, misses more)",
        )
        hnsw_ef: int = Field(64, ge=8, description="HNSW search breadth (knn: hnsw)")

    config: Config

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._index = None
        self._indexed = 0

    def _self_columns(self, positions: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        # exact neighbours outside the band, kept as _columns keeps a query's
        assert self._references is not None
        references = self._references.view
        band = self._band(positions)
        distances = np.where(band, np.inf, difference_columns(references, references[positions])).T  # (q, R)
        k = min(self.config.k, int((~band).sum(axis=0).min()))
        nearest = np.argpartition(distances, k - 1, axis=1)[:, :k]
        return self._kept(nearest, np.take_along_axis(distances, nearest, axis=1), band)

    def _neighbours(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, k) indices of each query's nearest references and their mean absolute differences."""
        assert self._references is not None
        references = self._references.view
        k = min(self.config.k, len(references))
        if self.config.knn == "exact":
            distances = difference_columns(references, queries).T  # (q, R)
            nearest = np.argpartition(distances, k - 1, axis=1)[:, :k]
            return nearest, np.take_along_axis(distances, nearest, axis=1)
        try:
            import faiss  # optional: only the approximate mode needs it
        except ImportError:
            raise PluginError("knn: hnsw needs FAISS: pip install 'slamfront[ann]' (faiss-cpu)") from None

        if self._index is None:
            self._index = faiss.IndexHNSWFlat(references.shape[1], 32)
            self._index.hnsw.efConstruction = 80
        if self._indexed < len(references):
            self._index.add(np.ascontiguousarray(references[self._indexed :], dtype=np.float32))
            self._indexed = len(references)
        self._index.hnsw.efSearch = max(self.config.hnsw_ef, k)
        _, nearest = self._index.search(np.ascontiguousarray(queries, dtype=np.float32), k)
        nearest = np.where(nearest >= 0, nearest, nearest.max(axis=1, keepdims=True))
        # the same mean absolute difference as the exact mode, on the k neighbours only
        gathered = references[nearest].astype(np.float32)
        distances = np.abs(gathered - queries[:, None, :].astype(np.float32)).sum(axis=2, dtype=np.float32)
        return nearest, distances / np.float32(references.shape[1])

    def _distance_count(self) -> int:
        """Exact neighbours compare every reference; HNSW's own distances inside the index
        are not counted, only the k recomputed per query."""
        if self.config.knn == "exact":
            return super()._distance_count()
        return min(self.config.k, len(self._reference_frames)) * len(self._query_frames)

    def _columns(self, queries: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None]]:
        nearest, distances = self._neighbours(queries)
        return self._kept(nearest, distances)

    def _kept(self, nearest: np.ndarray, distances: np.ndarray, band: np.ndarray | None = None,
              ) -> tuple[np.ndarray, list[np.ndarray | None]]:
        """Enhanced columns keeping each query's ``nearest`` references (their ``distances``;
        the rest at the column's largest kept one), and the rows worth scoring; ``band``
        entries (calibration) out of reach after the enhancement."""
        assert self._references is not None
        n_ref, n_queries = len(self._references), len(nearest)
        differences = np.repeat(distances.max(axis=1)[None, :], n_ref, axis=0).astype(np.float32)
        differences[nearest.T, np.arange(n_queries)[None, :]] = distances.T
        rows: list[np.ndarray | None] = [np.unique(row) for row in nearest]
        enhanced = enhance_contrast(differences, self.config.contrast_window)
        if band is not None:
            enhanced = np.where(band, enhanced.max(), enhanced)
        return enhanced, rows
