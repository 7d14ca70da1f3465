"""The paired-traversal datasets: Nordland, Gardens Point Walking, UofA, VPR-Bench, two folders.

Each class only reads its dataset's folder layout into a
:class:`~slamfront_plugins.sources.paired.PairedLayout`; selection, Rodrigues 2019's
experiments, frames and ground truth are shared (:mod:`.paired`).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from slamfront import DataError
from slamfront.data import DataPath, data_root, download_root
from slamfront.datasets import DatasetDownload
from slamfront.formats.npy import load_npy
from slamfront_plugins.downloads import GARDENS_POINT, NORDLAND, UOFA
from slamfront_plugins.sources.paired import PairedLayout, PairedTraversals, images_in


def dataset_folder(configured: Path | None, name: str) -> Path:
    """``configured``, else ``<data root>/<name>`` when present, else ``<download folder>/<name>``."""
    if configured is not None:
        return Path(configured)
    shared = data_root() / name
    return shared if shared.is_dir() else download_root() / name


def find_traversal(root: Path, traversal: str, dataset: str) -> Path:
    """``root/traversal``, or the same one or two folders down (archives often add a level)."""
    for candidate in (root / traversal, *root.glob(f"*/{traversal}"), *root.glob(f"*/*/{traversal}")):
        if candidate.is_dir():
            return candidate
    raise DataError(
        f"{root}: no {traversal!r} folder of the {dataset} dataset; get it with "
        f"`slamfront datasets download {dataset}` or set the source's root"
    )


class TraversalFolders(PairedTraversals):
    """Base of datasets with one image folder per traversal under a root (not a plugin)."""

    dataset: ClassVar[str] = ""
    """The dataset's name: its folder under the data root and its download."""

    class Config(PairedTraversals.Config):
        root: DataPath | None = Field(None, description="dataset folder; None: data root, then download folder")
        reference: str = Field("reference", description="folder of the reference traversal")
        query: str = Field("query", description="folder of the query traversal")

    def traversal_images(self) -> tuple[Path, list[Path], list[Path]]:
        """(dataset folder, reference images, query images)."""
        c = self.config
        root = dataset_folder(c.root, self.dataset)
        reference = images_in(find_traversal(root, c.reference, self.dataset))
        return root, reference, images_in(find_traversal(root, c.query, self.dataset))

    def layout(self) -> PairedLayout:
        root, reference, query = self.traversal_images()
        return PairedLayout.aligned(reference, query, f"{root} ({self.config.reference} vs {self.config.query})")


class Nordland(TraversalFolders):
    """Nordland railway (728 km, Norway), one season as reference and another as query.

    Reads ``<root>/<season>/*.png`` (default root: ``nordland`` under the data root, or
    the download folder). The seasons are frame-aligned: the same file name is the same
    place, so the ground truth pairs frames by name and refuses seasons whose names
    differ. Conventional use: reference summer, query winter.
    """

    name = "nordland"
    dataset = "nordland"
    downloads: ClassVar[tuple[DatasetDownload, ...]] = (NORDLAND,)

    class Config(TraversalFolders.Config):
        reference: str = Field("summer", description="season folder used as the reference traversal")
        query: str = Field("winter", description="season folder used as the query traversal")

    def layout(self) -> PairedLayout:
        c = self.config
        root, reference, query = self.traversal_images()
        query_names = {p.name for p in query}
        for path in reference:
            if path.name not in query_names:
                raise DataError(
                    f"{query[0].parent / path.name}: missing; the {c.query} season must hold the same frame "
                    f"names as {c.reference} (frame-aligned ground truth)"
                )
        if len(query) != len(reference):
            extra = next(p for p in query if p.name not in {r.name for r in reference})
            raise DataError(f"{extra}: has no {c.reference} counterpart (frame-aligned ground truth)")
        return PairedLayout.aligned(reference, query, str(root))


class GardensPoint(TraversalFolders):
    """Gardens Point Walking (QUT campus): two day walks and one night walk, frame-aligned.

    Reads ``<root>/{day_left,day_right,night_right}/Image*.jpg`` (200 each); frame i of
    every walk is the same place. Rodrigues 2019 uses reference day_left or day_right, query
    night_right.
    """

    name = "gardens_point"
    dataset = "gardens_point"
    downloads: ClassVar[tuple[DatasetDownload, ...]] = (GARDENS_POINT,)

    class Config(TraversalFolders.Config):
        reference: Literal["day_left", "day_right", "night_right"] = Field("day_left", description="reference walk")
        query: Literal["day_left", "day_right", "night_right"] = Field("night_right", description="query walk")


class UofA(TraversalFolders):
    """UofA day/evening (University of Alberta campus, Husky robot), frame-aligned.

    Reads ``<root>/[day_evening/]{day,evening}/<n>.jpg`` (the layout of the Fast-SeqSLAM
    release; files are numbered 1, 2, ... and sorted numerically).
    """

    name = "uofa"
    dataset = "uofa"
    downloads: ClassVar[tuple[DatasetDownload, ...]] = (UOFA,)

    class Config(TraversalFolders.Config):
        reference: str = Field("day", description="reference traversal folder")
        query: str = Field("evening", description="query traversal folder")


class VprBench(PairedTraversals):
    """A dataset in the VPR-Bench layout: ``query/``, ``ref/`` and ``ground_truth_new.npy``.

    The ground truth file is a NumPy object array with one row per query,
    ``[query index, [reference indices]]``, indices into the numerically sorted image
    lists (a pickle, read by an unpickler that builds arrays and nothing else). A query missing from it, or with
    an empty list, has no true match. ``tolerance`` widens each listed reference by
    that many frames (default 0: the file already lists every correct reference).
    """

    name = "vpr_bench"

    class Config(PairedTraversals.Config):
        root: DataPath = Field(description="folder holding query/, ref/ and ground_truth_new.npy")
        ground_truth: str = Field("ground_truth_new.npy", description="ground-truth file name inside root")
        tolerance: int = Field(0, ge=0, description="zeta: frames either side of a listed reference that also count")

    def layout(self) -> PairedLayout:
        root = Path(self.config.root)
        reference = images_in(root / "ref")
        query = images_in(root / "query")
        path = root / self.config.ground_truth
        if not path.is_file():
            raise DataError(f"{path}: no such ground-truth file")
        table = load_npy(path)  # an object array, rebuilt without running the pickle's code
        places = [np.empty(0, dtype=np.float64) for _ in query]
        if table.ndim != 2 or table.shape[1] != 2:
            raise DataError(f"{path}: expected rows of [query index, [reference indices]], got shape {table.shape}")
        if len(table) > len(query):
            raise DataError(f"{path}: {len(table)} ground-truth rows but only {len(query)} query images")
        for row, (q, refs) in enumerate(table):
            refs = np.atleast_1d(np.asarray(refs, dtype=np.int64))
            if not 0 <= int(q) < len(query):
                raise DataError(f"{path}: row {row}: query index {q} outside 0..{len(query) - 1}")
            if len(refs) and (refs.min() < 0 or refs.max() >= len(reference)):
                raise DataError(f"{path}: row {row}: reference index outside 0..{len(reference) - 1}")
            places[int(q)] = refs.astype(np.float64)
        return PairedLayout(reference, query, places)


class PairedFolders(PairedTraversals):
    """Any two image folders, paired by position or by a CSV of pairs.

    Without ``pairs`` the folders must hold the same number of images and image i of
    one is image i of the other. ``pairs`` is a CSV with two columns, query then
    reference (a header line is allowed), each a file name or a position
    (``index_base`` 0 or 1); a query may appear on several lines. Queries it does not
    list have no true match.
    """

    name = "paired_folders"

    class Config(PairedTraversals.Config):
        reference_folder: DataPath = Field(description="reference traversal images (natural order)")
        query_folder: DataPath = Field(description="query traversal images (natural order)")
        pairs: DataPath | None = Field(None, description="CSV of query,reference pairs; None: pair by position")
        index_base: Literal[0, 1] = Field(0, description="numbering of positions in the CSV")

    def layout(self) -> PairedLayout:
        c = self.config
        reference = images_in(Path(c.reference_folder))
        query = images_in(Path(c.query_folder))
        if c.pairs is None:
            return PairedLayout.aligned(reference, query, f"{c.reference_folder} vs {c.query_folder}")
        return PairedLayout(reference, query, self._read_pairs(Path(c.pairs), reference, query))

    def _read_pairs(self, path: Path, reference: list[Path], query: list[Path]) -> list[np.ndarray]:
        try:
            text = path.read_text()
        except OSError as exc:
            raise DataError(f"{path}: cannot read pairs: {exc.strerror or exc}") from exc
        by_name = ({p.name: i for i, p in enumerate(query)}, {p.name: i for i, p in enumerate(reference)})
        places: list[list[float]] = [[] for _ in query]
        for line_number, row in enumerate(csv.reader(text.splitlines()), start=1):
            if not row or row[0].strip().startswith("#"):
                continue
            if len(row) < 2:
                raise DataError(f"{path}:{line_number}: expected 'query,reference', got {','.join(row)!r}")
            resolved = [self._resolve(cell.strip(), names, count) for cell, names, count in
                        zip(row[:2], by_name, (len(query), len(reference)))]
            if None in resolved:
                if line_number == 1 and not any(cell.strip().lstrip("-").isdigit() for cell in row[:2]):
                    continue  # a header line
                side = "query" if resolved[0] is None else "reference"
                raise DataError(f"{path}:{line_number}: {side} {row[0 if side == 'query' else 1]!r} is not an image "
                                f"name or a position in range")
            places[resolved[0]].append(float(resolved[1]))  # type: ignore[index,arg-type]
        return [np.asarray(p, dtype=np.float64) for p in places]

    def _resolve(self, cell: str, names: dict[str, int], count: int) -> int | None:
        if cell in names:
            return names[cell]
        if cell.lstrip("-").isdigit():
            position = int(cell) - self.config.index_base
            return position if 0 <= position < count else None
        return None
