"""The ``euroc`` source: a EuRoC MAV sequence in the ASL layout (Burri et al. 2016).

Layout read (``root`` is the sequence folder holding ``mav0/``, or ``mav0`` itself)::

    mav0/cam0/data.csv                        #timestamp [ns],filename
    mav0/cam0/data/<timestamp>.png            grey 752x480
    mav0/cam0/sensor.yaml                     intrinsics, distortion, T_BS (camera in the body frame)
    mav0/state_groundtruth_estimate0/data.csv #timestamp, p_RS_R_x/y/z [m], q_RS_w/x/y/z, ...

The ground truth is the body's (IMU's) pose in the world; a frame's pose is the camera's,
``T_WB @ T_BS``, from the ground-truth row nearest its timestamp (within
``sync_tolerance_s``; the estimate is at 200 Hz). Frames outside the ground truth's time
span are dropped and counted. Images are undistorted (radial-tangential or equidistant).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import Field, model_validator

from slamfront import Camera, DataError, Frame, Plugin, PluginConfig, Source
from slamfront.core.geometry import pose_from_quaternion
from slamfront.core.loops import LoopGroundTruth
from slamfront.data import DataPath, path_inside
from slamfront.imageio import read_image
from slamfront.undistort import Undistortion
from slamfront_plugins.sources.recording import OdometryResampling, RecordingConfig, revisit_truth, selected

GROUND_TRUTH = "state_groundtruth_estimate0"


@dataclass(frozen=True)
class _Entry:
    number: int
    """The image's row in data.csv, 0-based."""
    stamp_ns: int
    image: Path
    pose: np.ndarray | None


class Euroc(Source):
    """A EuRoC MAV sequence (ASL layout): grey images, calibration and true camera poses.

    One camera's images with their nanosecond timestamps, its intrinsics and distortion
    from ``sensor.yaml`` (images are undistorted), and the ground-truth camera pose from
    ``state_groundtruth_estimate0`` composed with the camera's extrinsics ``T_BS``.
    """

    name = "euroc"

    class Config(RecordingConfig, OdometryResampling):
        root: DataPath = Field(description="sequence folder holding mav0/ (relative: under the data root)")
        camera: Literal["cam0", "cam1"] = Field("cam0", description="which camera of the stereo pair")
        ground_truth: bool = Field(True, description="read state_groundtruth_estimate0 (frames outside it are dropped)")
        sync_tolerance_s: float = Field(0.01, ge=0, description="largest gap between a frame and its ground-truth row")
        undistort: bool = Field(True, description="undistort the images by sensor.yaml's distortion")
        revisit_radius_m: float = Field(1.0, gt=0, description="stream loop truth: a revisit comes this close")

        @model_validator(mode="after")
        def _resampling_needs_poses(self) -> Euroc.Config:
            if self.resample_m > 0 and not self.ground_truth:
                raise ValueError("resample_m needs the ground truth's poses (ground_truth: true)")
            return self

    config: Config

    def __init__(self, config: PluginConfig | None = None) -> None:
        super().__init__(config)
        self.n_dropped = 0

    @cached_property
    def _mav(self) -> Path:
        root = Path(self.config.root)
        mav = root if (root / "cam0").is_dir() and root.name == "mav0" else root / "mav0"
        if not mav.is_dir():
            raise DataError(f"{root}: not a EuRoC sequence (no mav0/ folder)")
        return mav

    @cached_property
    def _sensor(self) -> tuple[Camera, str, np.ndarray, np.ndarray]:
        """(pinhole camera, distortion model, coefficients, T_BS) from the camera's sensor.yaml."""
        path = self._mav / self.config.camera / "sensor.yaml"
        try:
            text = path.read_text()
        except OSError as exc:
            raise DataError(f"{path}: cannot read the camera's calibration ({exc.strerror or exc})") from None
        lines = [line for line in text.splitlines() if not line.startswith("%YAML")]  # OpenCV's header
        try:
            data = yaml.safe_load("\n".join(lines))
            fx, fy, cx, cy = (float(v) for v in data["intrinsics"])
            width, height = (int(v) for v in data["resolution"])
            model = str(data.get("distortion_model", ""))
            coefficients = np.array([float(v) for v in data.get("distortion_coefficients", [])])
            t_bs = np.array(data["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
        except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{path}: expected intrinsics, resolution, distortion and T_BS ({exc})") from None
        return Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height), model, coefficients, t_bs

    def _read_csv(self, path: Path, columns: int) -> tuple[np.ndarray, list[list[str]]]:
        """Timestamps (int64 ns) and the remaining fields of a EuRoC csv (``#`` header lines skipped)."""
        try:
            lines = path.read_text().splitlines()
        except OSError as exc:
            raise DataError(f"{path}: cannot read ({exc.strerror or exc})") from None
        stamps, rows = [], []
        for number, line in enumerate(lines, 1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            fields = [f.strip() for f in line.split(",")]
            if len(fields) < columns:
                raise DataError(f"{path}:{number}: expected {columns} comma-separated fields, got {len(fields)}")
            try:
                stamps.append(int(fields[0]))
            except ValueError:
                raise DataError(f"{path}:{number}: {fields[0]!r} is not a timestamp in nanoseconds") from None
            rows.append(fields[1:])
        if not stamps:
            raise DataError(f"{path}: no rows")
        return np.array(stamps, dtype=np.int64), rows

    @cached_property
    def _entries(self) -> list[_Entry]:
        c = self.config
        folder = self._mav / c.camera
        stamps, rows = self._read_csv(folder / "data.csv", 2)
        images = [path_inside(folder / "data", row[0], f"{folder / 'data.csv'}") for row in rows]
        poses: list[np.ndarray | None] = [None] * len(stamps)
        truth_csv = self._mav / GROUND_TRUTH / "data.csv"
        self.n_dropped = 0
        if c.ground_truth and truth_csv.exists():
            truth_stamps, truth_rows = self._read_csv(truth_csv, 8)
            order = np.argsort(truth_stamps, kind="stable")
            truth_stamps = truth_stamps[order]
            at = np.clip(np.searchsorted(truth_stamps, stamps), 1, len(truth_stamps) - 1) if len(truth_stamps) > 1 \
                else np.zeros(len(stamps), dtype=np.int64)
            before = np.maximum(at - 1, 0)
            nearest = np.where(np.abs(truth_stamps[before] - stamps) <= np.abs(truth_stamps[at] - stamps), before, at)
            t_bs = self._sensor[3]
            tolerance = round(c.sync_tolerance_s * 1e9)
            for i, j in enumerate(nearest):
                if abs(int(truth_stamps[j]) - int(stamps[i])) > tolerance:
                    continue
                row = truth_rows[int(order[j])]
                try:
                    values = [float(v) for v in row[:7]]
                except ValueError:
                    raise DataError(f"{truth_csv}: row at {truth_stamps[j]} ns: expected numbers") from None
                qw, qx, qy, qz = values[3:7]
                poses[i] = pose_from_quaternion(np.array(values[:3]), np.array([qx, qy, qz, qw])) @ t_bs
            keep = [i for i, pose in enumerate(poses) if pose is not None]
            self.n_dropped = len(stamps) - len(keep)
            if not keep:
                raise DataError(f"{truth_csv}: no ground-truth row within {c.sync_tolerance_s} s of a frame")
        else:
            keep = list(range(len(stamps)))
        entries = [_Entry(i, int(stamps[i]), images[i], poses[i]) for i in keep]
        if c.resample_m > 0 and not truth_csv.exists():
            raise DataError(f"{truth_csv}: resample_m needs the ground truth's poses, and there is no such file")
        centres = np.array([e.pose[:3, 3] for e in entries]) if c.resample_m > 0 else None
        return selected(entries, c, centres)

    def check(self, stages: Mapping[str, Plugin]) -> None:
        """Read the layout (lists, calibration, ground truth) before the first frame."""
        self._entries  # noqa: B018 (cached: reads and validates the sequence's files)

    def __len__(self) -> int:
        return len(self._entries)

    def frames(self) -> Iterator[Frame]:
        camera, model, coefficients, _ = self._sensor
        undistortion = (Undistortion(camera, model, coefficients)
                        if self.config.undistort and Undistortion.needed(model, coefficients) else None)
        for index, entry in enumerate(self._entries):
            image = read_image(entry.image, "gray")
            if image.shape != (camera.height, camera.width):
                raise DataError(f"{entry.image}: {image.shape[1]}x{image.shape[0]}, but sensor.yaml says "
                                f"{camera.width}x{camera.height}")
            yield Frame(
                index=index, timestamp=entry.stamp_ns / 1e9,
                image=undistortion.image(image) if undistortion is not None else image,
                sequence_index=entry.number, name=entry.image.name,
                camera=camera, pose=entry.pose,
            )

    def statistics(self) -> dict[str, int]:
        return {"n_frames_dropped": self.n_dropped, "n_frames_dropped_no_pose": self.n_dropped}

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        if not self._entries or self._entries[0].pose is None:
            return None
        return revisit_truth([e.pose[:3, 3] for e in self._entries if e.pose is not None], self.config)

