"""The ``image_folder`` source: every image of a folder, in name order."""

from __future__ import annotations

from collections.abc import Iterator
from functools import cached_property
from pathlib import Path

import numpy as np
from pydantic import Field
from slamfront import DataError, Frame, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.data import DataPath
from slamfront.imageio import list_images, read_image


class ImageFolder(Source):
    """Images of one folder as a single stream, in natural name order (2 before 10).

    Relative folders are looked up under the data root (``$SLAMFRONT_DATA``). Timestamps
    are ``index / fps``. Loop ground truth is optional: groups of image names that show
    the same place, inline (``loops``) or in a text file (``loops_file``, one group per
    line, ``#`` starts a comment); a later image of a group revisits the earlier ones.
    """

    name = "image_folder"

    class Config(PluginConfig):
        folder: DataPath = Field(description="folder of images (relative: under the data root)")
        pattern: str = Field("*", description="glob pattern for the file names")
        step: int = Field(1, ge=1, description="use every step-th image")
        start: int = Field(0, ge=0, description="index of the first image used")
        limit: int | None = Field(None, ge=1, description="at most this many frames")
        fps: float = Field(10.0, gt=0, description="frames per second, for timestamps")
        loops: list[list[str]] = Field(
            default_factory=list, description="groups of image names showing the same place (loop ground truth)"
        )
        loops_file: DataPath | None = Field(
            None, description="text file of such groups, one per line: names separated by spaces"
        )

    @cached_property
    def files(self) -> list[Path]:
        c = self.config
        selected = list_images(Path(c.folder), c.pattern)[c.start :: c.step]
        return selected[: c.limit] if c.limit is not None else selected

    def __len__(self) -> int:
        return len(self.files)

    def frames(self) -> Iterator[Frame]:
        for index, path in enumerate(self.files):
            yield Frame(
                index=index,
                timestamp=index / self.config.fps,
                image=read_image(path),
                traversal="stream",
                sequence_index=self.config.start + index * self.config.step,
                name=path.name,
            )

    def _groups(self) -> list[tuple[str, list[str]]]:
        """(where it was written, names) of every group of same-place images."""
        groups = [(f"source.params.loops[{k}]", list(group)) for k, group in enumerate(self.config.loops)]
        path = self.config.loops_file
        if path is not None:
            try:
                lines = Path(path).read_text().splitlines()
            except OSError as exc:
                raise DataError(f"{path}: cannot read the loop labels: {exc.strerror or exc}") from exc
            for number, line in enumerate(lines, start=1):
                names = line.split("#", 1)[0].split()
                if names:
                    groups.append((f"{path}:{number}", names))
        return groups

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        groups = self._groups()
        if not groups:
            return None
        index = {path.name: k for k, path in enumerate(self.files)}
        rows: list[set[int]] = [set() for _ in self.files]
        for where, names in groups:
            if len(names) < 2:
                raise DataError(f"{where}: a loop group needs at least two image names, got {names}")
            unknown = [name for name in names if name not in index]
            if unknown:
                raise DataError(
                    f"{where}: {', '.join(unknown)} not among the frames of {self.config.folder} "
                    f"(after pattern/start/step/limit)"
                )
            frames = sorted(index[name] for name in names)
            for k, later in enumerate(frames):
                rows[later].update(frames[:k])
        queries = np.arange(len(self.files), dtype=np.int64)
        return LoopGroundTruth.from_rows(queries, [np.array(sorted(r), dtype=np.int64) for r in rows])
