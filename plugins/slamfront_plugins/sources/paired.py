"""Paired traversals: a reference run and a query run of the same route, with ground truth.

Every paired dataset (Nordland, Gardens Point, UofA, VPR-Bench layouts, two folders + a
CSV) is described the same way, by a :class:`PairedLayout`: the reference images in
order, the query images in order, and for each query the reference position(s) it
shows. :class:`PairedTraversals` turns a layout into a run:

- frames: every reference frame first (traversal ``reference``, frame indices
  0..R-1), then every query frame (``query``, R..R+Q-1), read lazily;
- ``start`` / ``step`` / ``limit`` select the same positions in both traversals;
- the experiments of Rodrigues 2019 §4.4 on the reference: ``replaced`` swaps a block for
  frames of another dataset (those queries then have no true match), ``reordered``
  moves a block to the end (the route is visited in another order);
- ``query_timing`` re-times the query (backwards, half or double speed, varying, stop
  and go: :mod:`slamfront.core.retiming`), its ground truth following its frames;
- ground truth by place (:meth:`LoopGroundTruth.from_places`): a match is correct when
  its reference frame shows a place within ``tolerance`` (zeta) of the query's place,
  counted in selected frames, so it stays right after a block is replaced or moved.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import DataError, Frame, Plugin, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.core.retiming import Timing, retimed_frames
from slamfront.data import DataPath
from slamfront.imageio import IMAGE_SUFFIXES, read_image
from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

Experiment = Literal["original", "replaced", "reordered"]

_TRAVERSAL_GAP_S = 60.0
"""Seconds between the last reference frame and the first query frame (timestamps must increase)."""


def natural_key(path: Path) -> tuple:
    """Sort key putting ``2.jpg`` before ``10.jpg`` (UofA, VPR-Bench number their files)."""
    return tuple(int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name))


def images_in(folder: Path) -> list[Path]:
    """The image files of ``folder`` in natural order. :raises DataError: missing or empty folder."""
    if not folder.is_dir():
        raise DataError(f"{folder}: no such image folder")
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=natural_key)
    if not files:
        raise DataError(f"{folder}: no images")
    return files


@dataclass(frozen=True)
class PairedLayout:
    """A paired dataset as found on disk, before selection and experiments.

    :ivar reference: reference images, in traversal order.
    :ivar query: query images, in traversal order.
    :ivar query_places: for each query, the reference positions (0-based) showing its
        place; empty when it has none.
    """

    reference: list[Path]
    query: list[Path]
    query_places: list[np.ndarray]

    @classmethod
    def aligned(cls, reference: list[Path], query: list[Path], what: str) -> PairedLayout:
        """Frame-aligned traversals: query i shows the place of reference i."""
        if len(reference) != len(query):
            raise DataError(
                f"{what}: the reference has {len(reference)} images but the query {len(query)}; "
                "frame-aligned traversals need the same number"
            )
        return cls(reference, query, [np.array([i], dtype=np.float64) for i in range(len(query))])


@dataclass(frozen=True)
class ReferenceItem:
    """One reference frame of the run: an image file, or frame ``foreign`` of the replacement."""

    path: Path | None
    place: float
    """Position along the route in selected frames; NaN for a frame of another dataset."""
    foreign: int = -1


class PairedTraversals(Source):
    """Base of the paired-traversal sources (not a plugin by itself): see the module docstring."""

    class Config(PluginConfig):
        tolerance: int = Field(3, ge=0, description="zeta: a match within this many (selected) frames is correct")
        start: int = Field(0, ge=0, description="first position used in both traversals")
        step: int = Field(1, ge=1, description="use every step-th position")
        limit: int | None = Field(None, ge=1, description="at most this many positions per traversal")
        experiment: Experiment = Field(
            "original", description="Rodrigues 2019 §4.4: original (1), replaced (2: a reference block from another "
            "dataset) or reordered (3: a reference block moved to the end)"
        )
        block_start: int | None = Field(
            None, ge=0, description="first reference frame of the block (selected frames); None: drawn from seed"
        )
        block_length: int | None = Field(
            None, ge=1, description="frames in the block; None: 15 % of the reference"
        )
        seed: int = Field(0, description="draws the block position when block_start is None")
        replacement_folder: DataPath | None = Field(
            None, description="experiment 2: images replacing the block (natural order); None: the synthetic "
            "world rendered at the reference image size (a dataset with no place on this route)"
        )
        unreadable_images: Literal["error", "blank"] = Field(
            "error", description="a corrupt image stops the run (error) or becomes a black frame, which "
            "descriptors mark featureless and detectors leave unanswered (blank)"
        )
        fps: float = Field(10.0, gt=0, description="frames per second, for timestamps")
        query_timing: Timing = Field(
            "original", description="re-time the query traversal after selection: reversed, half or double speed, "
            "speed varying 0.6x-1.8x, or stop_and_go (stops drawn from seed); the ground truth follows the frames "
            "(tests sequence detectors that must not assume the reference's pace)"
        )

        @model_validator(mode="after")
        def _replacement_needs_replaced(self) -> PairedTraversals.Config:
            if self.replacement_folder is not None and self.experiment != "replaced":
                raise ValueError("replacement_folder is only used by experiment: replaced")
            return self

    def layout(self) -> PairedLayout:
        """The dataset as found on disk. Subclasses read their folder layout here."""
        raise NotImplementedError

    def check(self, stages: Mapping[str, Plugin]) -> None:
        # read the folders and ground truth now, so bad data fails before the first frame
        _ = self.plan

    # --- the run --------------------------------------------------------------------------

    @cached_property
    def plan(self) -> tuple[list[ReferenceItem], list[Path], list[np.ndarray]]:
        """(reference items in run order, query images, each query's places in selected frames)."""
        c = self.config
        layout = self.layout()
        chosen = range(c.start, max(len(layout.reference), len(layout.query)), c.step)
        picked = list(chosen[: c.limit] if c.limit is not None else chosen)
        reference_positions = [p for p in picked if p < len(layout.reference)]
        query_positions = [p for p in picked if p < len(layout.query)]
        if not reference_positions or not query_positions:
            raise DataError(
                f"{self.name}: start={c.start}, step={c.step} selects no frames (reference {len(layout.reference)}, "
                f"query {len(layout.query)})"
            )
        references = [
            ReferenceItem(layout.reference[p], float(k)) for k, p in enumerate(reference_positions)
        ]
        # a query's place in selected-frame units: fractional when it falls between selected frames
        query_places = [(layout.query_places[p] - c.start) / c.step for p in query_positions]
        queries = [layout.query[p] for p in query_positions]
        if c.query_timing != "original" and len(queries) >= 2:
            shown = retimed_frames(len(queries), c.query_timing, c.seed).tolist()
            queries, query_places = [queries[k] for k in shown], [query_places[k] for k in shown]
        return self._apply_experiment(references), queries, query_places

    def block(self, n_reference: int) -> tuple[int, int]:
        """(first frame, length) of the experiment block among ``n_reference`` reference frames."""
        c = self.config
        length = c.block_length if c.block_length is not None else max(1, round(0.15 * n_reference))
        if c.block_start is None:
            margin = max(1, n_reference // 10)  # keep the block clear of the traversal ends
            high = n_reference - length - margin
            if high < margin:
                raise DataError(f"{self.name}: a block of {length} frames does not fit in {n_reference} reference frames")
            start = int(np.random.default_rng(c.seed).integers(margin, high + 1))
        else:
            start = c.block_start
        if start + length > n_reference:
            raise DataError(
                f"{self.name}: block_start={start} + block_length={length} runs past the {n_reference} reference frames"
            )
        return start, length

    def _apply_experiment(self, references: list[ReferenceItem]) -> list[ReferenceItem]:
        c = self.config
        if c.experiment == "original":
            return references
        start, length = self.block(len(references))
        if c.experiment == "reordered":
            return references[:start] + references[start + length :] + references[start : start + length]
        replaced = [ReferenceItem(None, float("nan"), foreign=k) for k in range(length)]
        return references[:start] + replaced + references[start + length :]

    def __len__(self) -> int:
        references, queries, _ = self.plan
        return len(references) + len(queries)

    def frames(self) -> Iterator[Frame]:
        references, queries, _ = self.plan
        dt = 1.0 / self.config.fps
        foreign = self._foreign_frames(references)
        last_shape: tuple[int, ...] | None = None
        for k, item in enumerate(references):
            if item.path is None:
                name, image = next(foreign)
            else:
                name, image = item.path.name, self._read(item.path, last_shape)
            last_shape = image.shape
            yield Frame(index=k, timestamp=k * dt, image=image, traversal="reference", sequence_index=k, name=name)
        offset = len(references)
        last_shape = None
        for k, path in enumerate(queries):
            image = self._read(path, last_shape)
            last_shape = image.shape
            yield Frame(
                index=offset + k, timestamp=(offset + k) * dt + _TRAVERSAL_GAP_S, image=image,
                traversal="query", sequence_index=k, name=path.name,
            )

    def _read(self, path: Path, shape: tuple[int, ...] | None) -> np.ndarray:
        try:
            return read_image(path)
        except DataError:
            if self.config.unreadable_images == "error":
                raise
            if shape is None:
                shape = self._shape_near(path)
            return np.zeros(shape, dtype=np.uint8)

    def _shape_near(self, path: Path) -> tuple[int, ...]:
        """The shape of the first readable image in ``path``'s folder (for a blank stand-in)."""
        for other in images_in(path.parent):
            try:
                return read_image(other).shape
            except DataError:
                continue
        raise DataError(f"{path.parent}: no readable image at all")

    def _foreign_frames(self, references: list[ReferenceItem]) -> Iterator[tuple[str, np.ndarray]]:
        """Experiment 2's replacement frames ``(name, image)``, at the reference image size and colour."""
        n = sum(1 for item in references if item.path is None)
        if n == 0:
            return iter(())
        sample = read_image(next(item.path for item in references if item.path is not None))
        height, width = sample.shape[:2]
        grey = bool(np.all(sample[..., 0] == sample[..., 1]) and np.all(sample[..., 1] == sample[..., 2]))
        return ((name, _fit(image, width, height, grey)) for name, image in self._replacements(n, width, height))

    def _replacements(self, n: int, width: int, height: int) -> Iterator[tuple[str, np.ndarray]]:
        folder = self.config.replacement_folder
        if folder is not None:
            files = images_in(Path(folder))
            if len(files) < n:
                raise DataError(f"{folder}: {len(files)} images, the replaced block needs {n}")
            return ((p.name, read_image(p)) for p in files[:n])
        from slamfront_plugins.sources.synthetic import SyntheticWorld  # renders with Open3D: import on use

        world = SyntheticWorld(SyntheticWorld.Config(
            seed=self.config.seed + 1, mode="paired", frames_per_traversal=n, route_length_m=max(40.0, 4.0 * n),
            image_width=max(width, 16), image_height=max(height, 16), reference_occluders=0,
        ))
        frames = world.frames()
        return ((f"synthetic-{k:05d}", next(frames).image) for k in range(n))

    # --- ground truth -------------------------------------------------------------------

    def loop_ground_truth(self) -> LoopGroundTruth:
        return self.loop_ground_truth_at(self.config.tolerance)

    def loop_ground_truth_at(self, tolerance: int) -> LoopGroundTruth:
        # each evaluation asks for it (and for every extra tolerance): built once per tolerance
        if tolerance not in self._truths:
            references, queries, query_places = self.plan
            n = len(references)
            self._truths[tolerance] = LoopGroundTruth.from_places(
                queries=np.arange(n, n + len(queries)),
                query_places=query_places,
                frames=np.arange(n),
                frame_places=np.array([item.place for item in references], dtype=np.float64),
                tolerance=tolerance,
            )
        return self._truths[tolerance]

    @cached_property
    def _truths(self) -> dict[int, LoopGroundTruth]:
        """Ground truths built so far, by tolerance (the plan never changes once made)."""
        return {}


def _fit(image: np.ndarray, width: int, height: int, grey: bool) -> np.ndarray:
    """Resize to ``width`` x ``height`` and, for grey references, drop the colour."""
    if image.shape[:2] != (height, width):
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    if grey and image.ndim == 3:
        image = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
    return image
