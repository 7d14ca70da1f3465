"""The ``image_folder`` source: every image of a folder, in name order."""

from __future__ import annotations

from collections.abc import Iterator
from functools import cached_property
from pathlib import Path

from pydantic import Field

from slamfront import Frame, PluginConfig, Source
from slamfront.data import DataPath
from slamfront.imageio import list_images, read_image


class ImageFolder(Source):
    """Images of one folder as a single stream, in natural name order (2 before 10).

    Relative folders are looked up under the data root (``$SLAMFRONT_DATA``). Timestamps
    are ``index / fps``. There is no ground truth.
    """

    name = "image_folder"

    class Config(PluginConfig):
        folder: DataPath = Field(description="folder of images (relative: under the data root)")
        pattern: str = Field("*", description="glob pattern for the file names")
        step: int = Field(1, ge=1, description="use every step-th image")
        start: int = Field(0, ge=0, description="index of the first image used")
        limit: int | None = Field(None, ge=1, description="at most this many frames")
        fps: float = Field(10.0, gt=0, description="frames per second, for timestamps")

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
