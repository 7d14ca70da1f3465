"""The ``nordland_stream`` source: the Nordland route driven in one season, then in another.

Kept minimal on purpose: the paired-traversal Nordland source (reference summer, query
winter) belongs to the loop-closure harness; this is its single-stream form, for
detectors that find loops within one stream (bag of words + Bayes filter), and could
become an option of that source.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import cached_property
from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from slamfront import DataError, Frame, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.data import DataPath
from slamfront.imageio import list_images, read_image


class NordlandStream(Source):
    """Nordland (NRK, CC BY) as one stream: the route in ``first`` season, then in ``second``.

    Frame i of the second season is at the place of frame i of the first (the
    dataset's frame alignment), so it revisits it: its true matches are first-season
    frames ``i - tolerance .. i + tolerance``. First-season frames have none. The
    folder holds ``<season>/images-NNNNN.png``; ``start``, ``step`` and ``limit`` pick
    the same frames in both seasons.
    """

    name = "nordland_stream"

    class Config(PluginConfig):
        root: DataPath = Field(Path("nordland"), description="the Nordland folder (relative: under the data root)")
        first: str = Field("summer", description="season driven first")
        second: str = Field("winter", description="season driven second (revisits the first)")
        start: int = Field(0, ge=0, description="first frame used, in each season")
        step: int = Field(1, ge=1, description="use every step-th frame")
        limit: int | None = Field(None, ge=1, description="at most this many frames per season")
        tolerance: int = Field(3, ge=0, description="zeta: first-season frames either side that still count")
        fps: float = Field(1.0, gt=0, description="frames per second, for timestamps")

        @model_validator(mode="after")
        def _two_seasons(self) -> NordlandStream.Config:
            if self.first == self.second:
                raise ValueError(f"first and second must be different seasons, both are {self.first!r}")
            return self

    @cached_property
    def seasons(self) -> tuple[list[Path], list[Path]]:
        c = self.config
        picked = []
        for season in (c.first, c.second):
            files = list_images(Path(c.root) / season)[c.start :: c.step]
            picked.append(files[: c.limit] if c.limit is not None else files)
        first, second = picked
        if [p.name for p in first] != [p.name for p in second]:
            raise DataError(
                f"{c.root}: {c.first}/ and {c.second}/ do not hold the same frame names "
                f"({len(first)} vs {len(second)} frames); the seasons must be frame-aligned"
            )
        return first, second

    def __len__(self) -> int:
        return 2 * len(self.seasons[0])

    def frames(self) -> Iterator[Frame]:
        first, second = self.seasons
        n = len(first)
        for lap, files in enumerate((first, second)):
            season = self.config.first if lap == 0 else self.config.second
            for k, path in enumerate(files):
                index = lap * n + k
                # one traversal: positions count through both seasons (the name tells the season)
                yield Frame(
                    index=index, timestamp=index / self.config.fps, image=read_image(path), traversal="stream",
                    sequence_index=index, name=f"{season}/{path.name}",
                )

    def loop_ground_truth(self) -> LoopGroundTruth:
        n = len(self.seasons[0])
        queries = np.arange(2 * n, dtype=np.int64)
        centres = np.where(queries >= n, queries - n, -1)
        return LoopGroundTruth.band(queries, centres, self.config.tolerance, valid=(0, n - 1))
