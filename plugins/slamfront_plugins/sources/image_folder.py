"""The ``image_folder`` source: every image of a folder, in name order (optionally with poses)."""

from __future__ import annotations

from collections.abc import Iterator
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from slamfront import Camera, DataError, Frame, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.data import DataPath
from slamfront.formats.poses import TRAJECTORY_READERS, Trajectory
from slamfront.imageio import list_images, read_image
from slamfront_plugins.sources.rgbd import KNOWN_CAMERAS, Intrinsics, KnownCamera


class ImageFolder(Source):
    """Images of one folder as a single stream, in natural name order (2 before 10).

    Relative folders are looked up under the data root (``$SLAMFRONT_DATA``). Timestamps
    are ``index / fps`` (or the pose file's, for TUM poses). Optionally a pose file gives
    each image's ground-truth camera-to-world pose (one per image in the folder, in
    order) and ``camera`` its intrinsics: an RGB-only sequence for the localizer. Loop
    ground truth is optional too: groups of image names that show the same place, inline
    (``loops``) or in a text file (``loops_file``, one group per line, ``#`` starts a
    comment); a later image of a group revisits the earlier ones.
    """

    name = "image_folder"

    class Config(PluginConfig):
        folder: DataPath = Field(description="folder of images (relative: under the data root)")
        pattern: str = Field("*", description="glob pattern for the file names")
        step: int = Field(1, ge=1, description="use every step-th image")
        start: int = Field(0, ge=0, description="index of the first image used")
        limit: int | None = Field(None, ge=1, description="at most this many frames")
        fps: float = Field(10.0, gt=0, description="frames per second, for timestamps")
        poses: DataPath | None = Field(
            None, description="ground-truth poses, one per image of the folder (relative: under the data root)"
        )
        pose_format: Literal["pose_lines", "redwood_log", "tum", "kitti"] = Field(
            "pose_lines", description="format of `poses`"
        )
        camera: Intrinsics | KnownCamera | None = Field(
            None, description="intrinsics (fx/fy/cx/cy or a known camera name), if known"
        )
        loops: list[list[str]] = Field(
            default_factory=list, description="groups of image names showing the same place (loop ground truth)"
        )
        loops_file: DataPath | None = Field(
            None, description="text file of such groups, one per line: names separated by spaces"
        )

    @cached_property
    def _all_files(self) -> list[Path]:
        return list_images(Path(self.config.folder), self.config.pattern)

    @cached_property
    def _selection(self) -> list[int]:
        c = self.config
        chosen = list(range(len(self._all_files)))[c.start :: c.step]
        return chosen[: c.limit] if c.limit is not None else chosen

    @property
    def files(self) -> list[Path]:
        return [self._all_files[i] for i in self._selection]

    @cached_property
    def trajectory(self) -> Trajectory | None:
        """The ground-truth poses, checked against the number of images."""
        c = self.config
        if c.poses is None:
            return None
        trajectory = TRAJECTORY_READERS[c.pose_format](Path(c.poses))
        if len(trajectory) != len(self._all_files):
            raise DataError(
                f"{c.poses}: {len(trajectory)} poses for {len(self._all_files)} images in {c.folder}"
                f"{'' if c.pattern == '*' else f' matching {c.pattern!r}'}"
            )
        return trajectory

    def _camera(self, image: np.ndarray) -> Camera | None:
        camera = self.config.camera
        if camera is None:
            return None
        fx, fy, cx, cy = KNOWN_CAMERAS[camera] if isinstance(camera, str) else (camera.fx, camera.fy, camera.cx, camera.cy)
        return Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=image.shape[1], height=image.shape[0])

    def __len__(self) -> int:
        return len(self._selection)

    def frames(self) -> Iterator[Frame]:
        trajectory = self.trajectory
        timed = trajectory is not None and self.config.pose_format == "tum"
        for index, position in enumerate(self._selection):
            path = self._all_files[position]
            image = read_image(path)
            yield Frame(
                index=index,
                timestamp=float(trajectory.timestamps[position]) if timed else index / self.config.fps,
                image=image,
                traversal="stream",
                sequence_index=position,
                name=path.name,
                camera=self._camera(image),
                pose=None if trajectory is None else trajectory.poses[position],
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
