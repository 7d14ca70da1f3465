"""RGB-D sequences: TUM RGB-D (``tum_rgbd``) and colour/depth folders (``rgbd_folder``).

Both yield frames with RGB, depth in metres, intrinsics and, when the dataset gives
them, ground-truth camera-to-world poses. Intrinsics come from the recipe: four
numbers, or the name of a known camera.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from slamfront import Camera, DataError, Frame, PluginConfig, Source
from slamfront.data import DataPath, path_inside
from slamfront.datasets import DatasetDownload
from slamfront.formats.poses import TRAJECTORY_READERS, Trajectory, numbered_fields, read_tum
from slamfront.formats.tum_rgbd import associate, read_file_list
from slamfront.imageio import list_images, read_depth, read_image
from slamfront_plugins.downloads import TUM_FR1_DESK, TUM_FR2_PIONEER_SLAM

KNOWN_CAMERAS = MappingProxyType(
    {
        # fx, fy, cx, cy
        "primesense": (525.0, 525.0, 319.5, 239.5),  # Redwood; also TUM's "ROS default"
        "tum_fr1": (517.3, 516.5, 318.6, 255.3),
        "tum_fr2": (520.9, 521.0, 325.1, 249.7),
        "tum_fr3": (535.4, 539.2, 320.1, 247.6),
        "icl_nuim": (481.2, 481.2, 319.5, 239.5),
        "slambook_room": (518.0, 519.0, 325.5, 253.5),
    }
)
KnownCamera = Literal["primesense", "tum_fr1", "tum_fr2", "tum_fr3", "icl_nuim", "slambook_room"]

POSE_READERS = TRAJECTORY_READERS

_FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])


class Intrinsics(PluginConfig):
    """Pinhole intrinsics in pixels."""

    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float


class RgbdConfig(PluginConfig):
    """What every RGB-D source needs."""

    camera: Intrinsics | KnownCamera = Field(
        "primesense", description="fx/fy/cx/cy, or a known camera: " + ", ".join(KNOWN_CAMERAS)
    )
    depth_scale: float = Field(1000.0, gt=0, description="raw depth units per metre (1000 mm, 5000 TUM/ICL)")
    start: int = Field(0, ge=0, description="first frame used")
    step: int = Field(1, ge=1, description="use every step-th frame")
    limit: int | None = Field(None, ge=1, description="at most this many frames")
    flip_y: bool = Field(
        False,
        description="the poses use a y-up camera and world (ICL-NUIM's POV-Ray convention): "
        "read them as diag(1,-1,1) T diag(1,-1,1), so they agree with the images",
    )


@dataclass(frozen=True)
class RgbdEntry:
    """One frame of a sequence before its pixels are read."""

    timestamp: float
    color: Path
    depth: Path
    pose: np.ndarray | None


class RgbdSequence(Source):
    """Shared loading for RGB-D sources: subclasses list the entries, this reads the pixels."""

    config: RgbdConfig

    def entries(self) -> list[RgbdEntry]:
        """Every frame of the sequence, in order, before start/step/limit."""
        raise NotImplementedError

    @cached_property
    def selected(self) -> list[RgbdEntry]:
        c = self.config
        chosen = self.entries()[c.start :: c.step]
        return chosen[: c.limit] if c.limit is not None else chosen

    def intrinsics(self) -> tuple[float, float, float, float]:
        camera = self.config.camera
        if isinstance(camera, str):
            return KNOWN_CAMERAS[camera]
        return camera.fx, camera.fy, camera.cx, camera.cy

    def __len__(self) -> int:
        return len(self.selected)

    def frames(self) -> Iterator[Frame]:
        fx, fy, cx, cy = self.intrinsics()
        for index, entry in enumerate(self.selected):
            image = read_image(entry.color)
            depth = read_depth(entry.depth, self.config.depth_scale, shape=image.shape[:2])
            camera = Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=image.shape[1], height=image.shape[0])
            yield Frame(
                index=index,
                timestamp=entry.timestamp,
                image=image,
                traversal="stream",
                sequence_index=self.config.start + index * self.config.step,
                name=entry.color.name,
                depth=depth,
                camera=camera,
                pose=entry.pose if entry.pose is None or not self.config.flip_y else _FLIP_Y @ entry.pose @ _FLIP_Y,
            )


class RgbdFolder(RgbdSequence):
    """Colour and depth images in two folders, with optional poses (Redwood, slambook, ICL-NUIM samples).

    Frames pair colour and depth files by name (natural order: 2 before 10), or by a
    match file of ``depth/x.png color/x.jpg`` lines (Redwood's ``rgbd.match``). Poses,
    if given, are camera-to-world, one per frame, in ``pose_lines`` (``tx ty tz qx qy qz
    qw``), ``redwood_log``, ``tum`` or ``kitti`` format. Timestamps are ``index / fps``
    unless the pose file has times (TUM).
    """

    name = "rgbd_folder"

    class Config(RgbdConfig):
        root: DataPath = Field(description="sequence folder (relative: under the data root)")
        color_dir: str = Field("color", description="colour images, relative to root")
        depth_dir: str = Field("depth", description="depth images, relative to root")
        match_file: str | None = Field(None, description="'depth color' pairs per line, relative to root")
        poses: str | None = Field(None, description="pose file relative to root (ground truth)")
        pose_format: Literal["pose_lines", "redwood_log", "tum", "kitti"] = "pose_lines"
        intrinsics_file: str | None = Field(
            None, description="Open3D camera JSON (intrinsic_matrix, column-major) overriding `camera`"
        )
        fps: float = Field(30.0, gt=0, description="frame rate for timestamps")

    config: Config

    def intrinsics(self) -> tuple[float, float, float, float]:
        if self.config.intrinsics_file is None:
            return super().intrinsics()
        path = Path(self.config.root) / self.config.intrinsics_file
        try:
            matrix = json.loads(path.read_text())["intrinsic_matrix"]
            k = np.array(matrix, dtype=np.float64).reshape(3, 3).T  # Open3D stores it column-major
        except FileNotFoundError:
            raise DataError(f"{path}: no such intrinsics file") from None
        except (KeyError, ValueError, TypeError) as exc:
            raise DataError(f"{path}: intrinsic_matrix: expected 9 numbers ({exc})") from None
        return k[0, 0], k[1, 1], k[0, 2], k[1, 2]

    def _pairs(self) -> list[tuple[Path, Path]]:
        root = Path(self.config.root)
        if not root.is_dir():
            raise DataError(f"{root}: no such sequence folder")
        if self.config.match_file is not None:
            pairs = []
            match_file = root / self.config.match_file
            for number, fields in numbered_fields(match_file):
                if len(fields) != 2:
                    raise DataError(f"{match_file}:{number}: expected 'depth color'")
                depth, color = (path_inside(root, name, f"{match_file}:{number}") for name in fields)
                pairs.append((color, depth))
            return pairs
        colors = list_images(root / self.config.color_dir)
        depths = list_images(root / self.config.depth_dir)
        by_stem = {p.stem: p for p in depths}
        pairs = []
        for color in colors:
            depth = by_stem.get(color.stem)
            if depth is None:
                raise DataError(f"{color}: no depth image named {color.stem}.* in {root / self.config.depth_dir}")
            pairs.append((color, depth))
        return pairs

    def entries(self) -> list[RgbdEntry]:
        pairs = self._pairs()
        trajectory: Trajectory | None = None
        if self.config.poses is not None:
            path = Path(self.config.root) / self.config.poses
            trajectory = POSE_READERS[self.config.pose_format](path)
            if len(trajectory) != len(pairs):
                raise DataError(f"{path}: {len(trajectory)} poses for {len(pairs)} frames")
        timed = trajectory is not None and self.config.pose_format == "tum"
        return [
            RgbdEntry(
                timestamp=float(trajectory.timestamps[i]) if timed else i / self.config.fps,
                color=color,
                depth=depth,
                pose=None if trajectory is None else trajectory.poses[i],
            )
            for i, (color, depth) in enumerate(pairs)
        ]


class TumRgbd(RgbdSequence):
    """A TUM RGB-D benchmark sequence: ``rgb.txt``, ``depth.txt`` and ``groundtruth.txt``.

    Colour and depth are associated by timestamp as the benchmark's ``associate.py``
    does (closest pairs first, within ``max_difference`` seconds); each frame then takes
    the ground-truth pose closest in time (within ``max_difference``), if any. Depth PNGs
    are 16-bit with 5000 units per metre.
    """

    name = "tum_rgbd"
    downloads: ClassVar[tuple[DatasetDownload, ...]] = (TUM_FR1_DESK, TUM_FR2_PIONEER_SLAM)

    class Config(RgbdConfig):
        root: DataPath = Field(description="sequence folder (relative: under the data root)")
        camera: Intrinsics | KnownCamera = Field("tum_fr1", description="fr1/fr2/fr3 intrinsics or four numbers")
        depth_scale: float = Field(5000.0, gt=0)
        max_difference: float = Field(0.02, gt=0, description="association tolerance in seconds")
        ground_truth: bool = Field(True, description="read groundtruth.txt when present")
        require_pose: bool = Field(False, description="drop frames without a ground-truth pose")

    config: Config

    def entries(self) -> list[RgbdEntry]:
        root = Path(self.config.root)
        if not root.is_dir():
            raise DataError(f"{root}: no such TUM sequence folder")
        rgb_stamps, rgb_names, rgb_lines = read_file_list(root / "rgb.txt")
        depth_stamps, depth_names, _ = read_file_list(root / "depth.txt")
        pairs = associate(rgb_stamps, depth_stamps, self.config.max_difference)
        if len(pairs) == 0:
            raise DataError(
                f"{root / 'rgb.txt'}: no colour timestamp is within {self.config.max_difference} s of one in depth.txt"
            )
        trajectory = None
        gt_path = root / "groundtruth.txt"
        if self.config.ground_truth and gt_path.exists():
            trajectory = read_tum(gt_path)
        pose_of: dict[int, np.ndarray] = {}
        if trajectory is not None:
            for i, j in associate(rgb_stamps[pairs[:, 0]], trajectory.timestamps, self.config.max_difference):
                pose_of[int(i)] = trajectory.poses[j]
            if self.config.require_pose and not pose_of:
                raise DataError(f"{gt_path}: no pose is within {self.config.max_difference} s of a frame")
        entries = []
        for k, (i, j) in enumerate(pairs):
            pose = pose_of.get(k)
            if self.config.require_pose and pose is None:
                continue
            color = path_inside(root, rgb_names[i], f"{root / 'rgb.txt'}:{rgb_lines[i]}")
            depth = path_inside(root, depth_names[j], f"{root / 'depth.txt'}")
            if not color.exists():
                raise DataError(f"{root / 'rgb.txt'}:{rgb_lines[i]}: {color} does not exist")
            entries.append(RgbdEntry(float(rgb_stamps[i]), color, depth, pose))
        return entries
