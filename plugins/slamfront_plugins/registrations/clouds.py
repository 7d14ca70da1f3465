"""One RGB-D frame to a registration-ready cloud (Barbosa 2017, 4.2.2.2, first steps).

Back-projection with the frame's intrinsics and truncation, statistical outlier removal,
voxel grid, normals oriented to the viewpoint (the camera centre), then FPFH (Open3D) or
PFH (:mod:`slamfront.core.point_features`). Everything stays in the camera frame; the
caller places clouds in the world.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from slamfront import DataError, Frame
from slamfront.core.clouds import back_project
from slamfront.core.point_features import hybrid_neighbours, pfh
from slamfront.lazy import lazy_module
from slamfront_plugins.registrations.config import FeatureIcpConfig

o3d = lazy_module("open3d")  # loads on first use: listing plugins does not import it

T = TypeVar("T")


class UnusableFrame(Exception):
    """A frame gives no cloud worth registering; the message says why (reported, not fatal)."""


@dataclass
class StepTimer:
    """Wall time per named step, summed over calls."""

    seconds: dict[str, float] = field(default_factory=dict)

    def run(self, step: str, work: Callable[[], T]) -> T:
        start = time.perf_counter()
        try:
            return work()
        finally:
            self.seconds[step] = self.seconds.get(step, 0.0) + time.perf_counter() - start


@dataclass
class PreparedCloud:
    """A frame's cloud in its camera frame, ready to register."""

    frame: int
    cloud: o3d.geometry.PointCloud
    """Downsampled, with normals pointing to the camera."""
    features: o3d.pipelines.registration.Feature | None
    model_points: np.ndarray
    """(M, 3) float32 at the model voxel size, for the global model."""
    model_colors: np.ndarray
    """(M, 3) uint8 RGB."""

    @property
    def n_points(self) -> int:
        return len(self.cloud.points)


def describe(frame: Frame) -> str:
    """How messages name a frame: its index and, when known, its file."""
    return f"frame {frame.index}" + (f" ({frame.name})" if frame.name else "")


def check_depth(frame: Frame) -> None:
    """A frame must carry depth and intrinsics matching its image.

    :raises DataError: naming the frame and the field (this is a source that cannot
        feed a registration, not one bad frame).
    """
    if frame.depth is None:
        raise DataError(f"{describe(frame)}: depth: the source gives no depth image; registration needs an RGB-D source")
    if frame.camera is None:
        raise DataError(f"{describe(frame)}: camera: the source gives no intrinsics; registration needs them")
    image_shape = tuple(frame.image.shape[:2])
    if tuple(frame.depth.shape) != image_shape:
        raise DataError(
            f"{describe(frame)}: depth: {frame.depth.shape[1]}x{frame.depth.shape[0]} but the image is "
            f"{image_shape[1]}x{image_shape[0]} (depth must be registered to the colour image)"
        )


def _no_depth_reason(frame: Frame, config: FeatureIcpConfig) -> str:
    depth = np.asarray(frame.depth)
    positive = depth[np.isfinite(depth) & (depth > 0)]
    window = f"({config.min_depth_m:g}, {config.max_depth_m:g}] m"
    if positive.size == 0:
        return f"{describe(frame)}: depth is all zero (no sensor return in any pixel)"
    median = float(np.median(positive))
    hint = " (check the source's depth_scale)" if not config.min_depth_m < median <= config.max_depth_m else ""
    return f"{describe(frame)}: only {positive.size} pixels with depth, few in {window}; median depth {median:.3g} m{hint}"


def prepare_cloud(frame: Frame, config: FeatureIcpConfig, timer: StepTimer) -> PreparedCloud:
    """Turn one RGB-D frame into a :class:`PreparedCloud`.

    :raises UnusableFrame: all-zero depth, or too few points after filtering.
    :raises DataError: the frame has no depth or intrinsics, or they do not fit the image.
    """
    check_depth(frame)
    points, pixels = timer.run(
        "cloud",
        lambda: back_project(
            frame.depth, frame.camera.matrix, config.min_depth_m, config.max_depth_m, config.pixel_stride
        ),
    )
    if len(points) < config.min_points:
        raise UnusableFrame(_no_depth_reason(frame, config))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    colors = frame.image[pixels[:, 0], pixels[:, 1]]
    if colors.ndim == 1:  # a grey image
        colors = np.repeat(colors[:, None], 3, axis=1)
    cloud.colors = o3d.utility.Vector3dVector(colors.astype(np.float64) / 255.0)
    try:
        return prepare_points(frame.index, cloud, config, timer)
    except UnusableFrame as exc:
        raise UnusableFrame(f"{describe(frame)}: {exc} from {len(points)} pixels with depth") from None


def prepare_points(
    frame: int,
    cloud: o3d.geometry.PointCloud,
    config: FeatureIcpConfig,
    timer: StepTimer,
    viewpoint: np.ndarray | None = None,
) -> PreparedCloud:
    """Filter, downsample, orient normals to ``viewpoint`` (default: the origin, the
    camera centre) and describe a cloud.

    :raises UnusableFrame: too few points are left after filtering.
    """
    if config.outlier_neighbours > 0:
        cloud = timer.run(
            "outliers", lambda: cloud.remove_statistical_outlier(config.outlier_neighbours, config.outlier_std_ratio)[0]
        )
    down = timer.run("downsample", lambda: cloud.voxel_down_sample(config.voxel_size_m))
    if len(down.points) < config.min_points:
        raise UnusableFrame(
            f"too few points after filtering: {len(down.points)} at voxel {config.voxel_size_m:g} m "
            f"(min_points {config.min_points})"
        )
    timer.run("normals", lambda: _estimate_normals(down, config, np.zeros(3) if viewpoint is None else viewpoint))
    features = timer.run("features", lambda: compute_features(down, config))
    model = down if config.model_voxel_m == config.voxel_size_m else cloud.voxel_down_sample(config.model_voxel_m)
    colors = np.asarray(model.colors) if model.has_colors() else np.full((len(model.points), 3), 0.7)
    return PreparedCloud(
        frame=frame,
        cloud=down,
        features=features,
        model_points=np.asarray(model.points, dtype=np.float32),
        model_colors=np.round(colors * 255.0).astype(np.uint8),
    )


def _estimate_normals(cloud: o3d.geometry.PointCloud, config: FeatureIcpConfig, viewpoint: np.ndarray) -> None:
    radius = config.normal_radius_voxels * config.voxel_size_m
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=config.normal_max_nn))
    # normals face the viewpoint: n . (v - p) > 0 (Barbosa 2017, eq. 4.7)
    cloud.orient_normals_towards_camera_location(np.asarray(viewpoint, dtype=np.float64))


def compute_features(
    cloud: o3d.geometry.PointCloud, config: FeatureIcpConfig
) -> o3d.pipelines.registration.Feature | None:
    """FPFH or PFH of every point of a cloud with normals (None when features are off)."""
    radius = config.feature_radius_voxels * config.voxel_size_m
    if config.feature == "none":
        return None
    if config.feature == "fpfh":
        return o3d.pipelines.registration.compute_fpfh_feature(
            cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=config.feature_max_nn)
        )
    points = np.asarray(cloud.points)
    histograms = pfh(points, np.asarray(cloud.normals), hybrid_neighbours(points, radius, config.feature_max_nn))
    feature = o3d.pipelines.registration.Feature()
    feature.resize(histograms.shape[1], histograms.shape[0])
    feature.data = np.ascontiguousarray(histograms.T)
    return feature


@contextmanager
def open3d_threads(threads: int) -> Iterator[None]:
    """Open3D limited to ``threads`` threads (0: its default) inside the block.

    Open3D's limit is process-wide (oneTBB has no per-call setting), so the previous
    limit is restored on the way out.
    """
    previous = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(threads)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(previous)
