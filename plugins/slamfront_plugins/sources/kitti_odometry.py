"""The ``kitti_odometry`` source: a sequence of the KITTI odometry benchmark (Geiger et al. 2012).

Layout read (``root`` is the dataset folder)::

    sequences/NN/image_0/000000.png ...   left grey (image_1 right grey, image_2/3 colour)
    sequences/NN/calib.txt                P0: .. P3: (3x4 projections of the rectified cameras), Tr:
    sequences/NN/times.txt                seconds of each frame
    poses/NN.txt                          12 numbers per line: camera 0's pose in the first frame's camera 0

Images are rectified, so the intrinsics are the projection's ``K``. The ground truth is
camera 0's; for another camera the pose is moved by that camera's offset in ``calib.txt``
(``P_k = K [I | t_k]``: the camera sits at ``-t_k`` in camera 0's frame).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, field_validator

from slamfront import Camera, DataError, Frame, Plugin, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.data import DataPath
from slamfront.formats.poses import numbered_fields, read_kitti
from slamfront.imageio import list_images, read_image
from slamfront_plugins.sources.recording import OdometryResampling, RecordingConfig, revisit_truth, selected

CameraFolder = Literal["image_0", "image_1", "image_2", "image_3"]


class KittiOdometry(Source):
    """A KITTI odometry sequence: rectified images, times, calibration and true poses.

    One camera's images, ``times.txt`` timestamps, intrinsics from ``calib.txt`` and, for
    sequences 00-10, the ground-truth poses moved to the chosen camera.
    """

    name = "kitti_odometry"

    class Config(RecordingConfig, OdometryResampling):
        root: DataPath = Field(description="dataset folder holding sequences/ and poses/ (relative: under the data root)")
        sequence: str = Field("00", description="sequence number, two digits (00-21)")
        camera: CameraFolder = Field("image_0", description="image_0/1: grey left/right; image_2/3: colour left/right")
        poses: bool = Field(True, description="read poses/NN.txt when it exists (sequences 00-10)")
        revisit_radius_m: float = Field(5.0, gt=0, description="stream loop truth: a revisit comes this close")

        @field_validator("sequence")
        @classmethod
        def _two_digits(cls, value: str) -> str:
            if not value.isdigit():
                raise ValueError(f"a KITTI sequence is a number such as '00', got {value!r}")
            return f"{int(value):02d}"

    config: Config

    @cached_property
    def _folder(self) -> Path:
        folder = Path(self.config.root) / "sequences" / self.config.sequence
        if not folder.is_dir():
            raise DataError(f"{folder}: no such KITTI sequence folder")
        return folder

    @cached_property
    def _projection(self) -> np.ndarray:
        """The 3x4 projection ``P_k`` of the chosen camera, from calib.txt."""
        path = self._folder / "calib.txt"
        key = "P" + self.config.camera[-1] + ":"
        for number, fields in numbered_fields(path):
            if fields and fields[0] == key:
                try:
                    values = np.array([float(v) for v in fields[1:]], dtype=np.float64)
                except ValueError:
                    raise DataError(f"{path}:{number}: {key} needs 12 numbers") from None
                if values.shape != (12,):
                    raise DataError(f"{path}:{number}: {key} needs 12 numbers, got {len(values)}")
                return values.reshape(3, 4)
        raise DataError(f"{path}: no {key} line (the projection of {self.config.camera})")

    @cached_property
    def _all(self) -> tuple[list[Path], np.ndarray, np.ndarray | None]:
        """Every image, its timestamp and (when known) the camera's pose."""
        images = list_images(self._folder / self.config.camera, "*.png")
        times_path = self._folder / "times.txt"
        stamps = []
        for number, fields in numbered_fields(times_path):
            try:
                stamps.append(float(fields[0]))
            except ValueError:
                raise DataError(f"{times_path}:{number}: {fields[0]!r} is not a time in seconds") from None
        if len(stamps) != len(images):
            raise DataError(f"{times_path}: {len(stamps)} times for {len(images)} images in {self.config.camera}")
        poses = None
        pose_path = Path(self.config.root) / "poses" / f"{self.config.sequence}.txt"
        if self.config.poses and pose_path.exists():
            poses = read_kitti(pose_path).poses
            if len(poses) != len(images):
                raise DataError(f"{pose_path}: {len(poses)} poses for {len(images)} images")
            projection = self._projection
            offset = np.eye(4)
            offset[:3, 3] = -np.linalg.solve(projection[:, :3], projection[:, 3])  # this camera in camera 0's frame
            poses = poses @ offset
        return images, np.array(stamps, dtype=np.float64), poses

    @cached_property
    def _chosen(self) -> list[int]:
        poses = self._all[2]
        if self.config.resample_m > 0 and poses is None:
            raise DataError(f"{Path(self.config.root) / 'poses' / f'{self.config.sequence}.txt'}: resample_m needs the "
                            "sequence's poses, and there is no such file")
        return selected(range(len(self._all[0])), self.config, None if poses is None else poses[:, :3, 3])

    def check(self, stages: Mapping[str, Plugin]) -> None:
        """Read the layout (images, times, calibration, poses) before the first frame."""
        self._all  # noqa: B018 (cached: reads and validates the sequence's files)
        self._projection  # noqa: B018

    def __len__(self) -> int:
        return len(self._chosen)

    def frames(self) -> Iterator[Frame]:
        images, stamps, poses = self._all
        k = self._projection[:, :3]
        grey = self.config.camera in ("image_0", "image_1")
        for index, i in enumerate(self._chosen):
            image = read_image(images[i], "gray" if grey else "rgb")
            camera = Camera(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]), cy=float(k[1, 2]),
                            width=image.shape[1], height=image.shape[0])
            yield Frame(
                index=index, timestamp=float(stamps[i]), image=image, sequence_index=i, name=images[i].name,
                camera=camera, pose=None if poses is None else poses[i],
            )

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        poses = self._all[2]
        if poses is None:
            return None
        return revisit_truth(poses[self._chosen, :3, 3], self.config)
