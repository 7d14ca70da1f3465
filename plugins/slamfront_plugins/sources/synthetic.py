"""The ``synthetic`` source: a procedural street world slamfront renders itself."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from slamfront import Camera, Frame, PluginConfig, Source
from slamfront.core.loops import LoopGroundTruth
from slamfront.core.retiming import Timing, equal_distance, retimed_positions
from slamfront.frame import Traversal
from slamfront.limits import check_limit
from slamfront_plugins.sources.synthetic_world import Illumination, Lighting, StreetWorld, occluders_at

logger = logging.getLogger(__name__)


class SyntheticWorld(Source):
    """A seeded 3-D street world rendered along a route that revisits its places.

    ``mode: paired`` gives a reference traversal then a query traversal of the same
    route (query frame i is at the place of reference frame i) under other
    illumination, a small viewpoint offset and moving occluders. ``mode: stream`` drives
    the route ``laps`` times in one stream; later laps revisit the first. Frames carry
    RGB, depth, intrinsics and the ground-truth pose; everything is deterministic.
    ``query_timing`` drives the query (paired) or every second lap (stream) at another
    pace or backwards (:mod:`slamfront.core.retiming`; backwards, the camera still faces
    the route's forward direction); frame i of such a pass is at the route position its
    speed profile reached, and the ground truth follows it.
    """

    name = "synthetic"

    class Config(PluginConfig):
        seed: int = Field(0, description="world and noise seed")
        mode: Literal["paired", "stream"] = Field("paired", description="two traversals, or one stream of laps")
        frames_per_traversal: int = Field(400, ge=2, description="frames per traversal (or per lap)")
        laps: int = Field(2, ge=1, description="laps driven in stream mode")
        route_length_m: float = Field(400.0, gt=20, description="length of the closed street")
        street_width_m: float = Field(10.0, gt=2)
        image_width: int = Field(160, ge=16)
        image_height: int = Field(120, ge=16)
        fov_deg: float = Field(90.0, gt=10, lt=170, description="horizontal field of view")
        speed_mps: float = Field(5.0, gt=0, description="driving speed (sets timestamps)")
        reference_illumination: Illumination = "day"
        query_illumination: Illumination = "dusk"
        stream_illuminations: list[Illumination] = Field(
            default_factory=lambda: ["day", "dusk"], description="illumination of each lap, cycled"
        )
        query_lateral_offset_m: float = Field(0.3, description="query camera moved left by this much")
        query_yaw_offset_deg: float = Field(2.0, description="query camera turned left by this much")
        reference_occluders: int = Field(0, ge=0)
        query_occluders: int = Field(15, ge=0, description="moving people and vehicles in the query")
        noise_std: float = Field(2.0, ge=0, description="sensor noise, grey levels")
        max_depth_m: float = Field(40.0, gt=0, description="depth beyond this reads 0 (no return)")
        tolerance: int = Field(3, ge=0, description="zeta: frames either side that still count as a match")
        revisit_radius_m: float = Field(3.0, gt=0, description="stream mode: a revisit is this close")
        shuffle: bool = Field(
            False, description="give the query traversal (paired) or the whole stream in a random order (kidnapped robot)"
        )
        shuffle_seed: int = Field(0, description="seed of the shuffled order")
        query_timing: Timing = Field(
            "original", description="the query traversal (paired) or laps 2, 4, ... (stream) driven backwards "
            "(reversed), at half or double speed, at a speed varying 0.6x-1.8x, or stop_and_go (stops drawn from "
            "seed); original: at the reference's pace"
        )
        resample_m: float = Field(
            0.0, ge=0, description="SMART (Pepperell et al. 2014): every pass keeps one frame per this many metres "
            "travelled, by its odometry (the poses), so traversals driven at different paces are matched at equal "
            "distance; 0: every frame (the default: a camera-only user has no odometry)"
        )
        own_patterns: bool = Field(
            False, description="surface patterns (road, bricks, signs) depend on the world seed too; false: on the place "
            "only, so two worlds share them at one place of the route",
        )

        # sizes a recipe (or a log's recipe) can make absurd, checked before anything is allocated
        @field_validator("frames_per_traversal")
        @classmethod
        def _frames_bounded(cls, value: int, info: ValidationInfo) -> int:
            passes = 2 if info.data.get("mode") == "paired" else 1
            check_limit("frames", value * passes, "the number of frames")
            return value

        @field_validator("laps")
        @classmethod
        def _laps_bounded(cls, value: int, info: ValidationInfo) -> int:
            if info.data.get("mode") == "stream":
                check_limit("frames", value * info.data.get("frames_per_traversal", 1), "frames_per_traversal x laps")
            return value

        @field_validator("route_length_m")
        @classmethod
        def _route_bounded(cls, value: float) -> float:
            check_limit("world_length_m", value, "the route length in metres")
            return value

        @field_validator("image_height")
        @classmethod
        def _image_bounded(cls, value: int, info: ValidationInfo) -> int:
            check_limit("image_pixels", value * info.data.get("image_width", 1), "image_width x image_height")
            return value

        @model_validator(mode="after")
        def _lap_illuminations(self) -> SyntheticWorld.Config:
            if not self.stream_illuminations:
                raise ValueError("stream_illuminations needs at least one entry")
            return self

    @cached_property
    def world(self) -> StreetWorld:
        c = self.config
        return StreetWorld(c.seed, c.route_length_m, c.street_width_m, c.own_patterns)

    @property
    def camera(self) -> Camera:
        c = self.config
        f = (c.image_width / 2) / np.tan(np.deg2rad(c.fov_deg) / 2)
        return Camera(fx=f, fy=f, cx=(c.image_width - 1) / 2, cy=(c.image_height - 1) / 2,
                      width=c.image_width, height=c.image_height)

    @property
    def step_m(self) -> float:
        return self.config.route_length_m / self.config.frames_per_traversal

    def _passes(self) -> list[tuple[Traversal, Illumination, float, float, int]]:
        """(traversal, illumination, lateral offset, yaw offset, occluders) per pass."""
        c = self.config
        if c.mode == "paired":
            return [
                ("reference", c.reference_illumination, 0.0, 0.0, c.reference_occluders),
                ("query", c.query_illumination, c.query_lateral_offset_m, c.query_yaw_offset_deg, c.query_occluders),
            ]
        passes = []
        for lap in range(c.laps):
            changed = lap % 2 == 1
            passes.append((
                "stream",
                c.stream_illuminations[lap % len(c.stream_illuminations)],
                c.query_lateral_offset_m if changed else 0.0,
                c.query_yaw_offset_deg if changed else 0.0,
                c.query_occluders if lap > 0 else c.reference_occluders,
            ))
        return passes

    def pass_positions(self, pass_number: int) -> np.ndarray:
        """(m,) float route positions, in reference frames, of the frames of a pass (re-timed
        passes: the query, or every second lap of a stream)."""
        c = self.config
        n = c.frames_per_traversal
        retimed = pass_number == 1 if c.mode == "paired" else pass_number % 2 == 1
        positions = np.arange(n, dtype=np.float64)
        if retimed and c.query_timing != "original":
            positions = retimed_positions(n, c.query_timing, c.seed + pass_number)
        if c.resample_m > 0:
            positions = positions[equal_distance(positions * self.step_m, c.resample_m)]
        return positions

    def __len__(self) -> int:
        return sum(len(self.pass_positions(p)) for p in range(len(self._passes())))

    def schedule(self) -> list[tuple[int, int]]:
        """(pass number, frame k of that pass) of each frame, in the order they are given.

        Pass by pass, k = 0, 1, ...; with ``shuffle``, the query pass (paired) or the
        whole stream comes in a seeded random order. Each frame's pixels and pose depend
        only on (pass, k), never on the order.
        """
        c = self.config
        order = [(p, k) for p in range(len(self._passes())) for k in range(len(self.pass_positions(p)))]
        if not c.shuffle:
            return order
        first = c.frames_per_traversal if c.mode == "paired" else 0
        shuffled = np.random.default_rng(c.shuffle_seed).permutation(len(order) - first)
        return order[:first] + [order[first + int(i)] for i in shuffled]

    def frames(self) -> Iterator[Frame]:
        n = self.config.frames_per_traversal
        dt = self.step_m / self.config.speed_mps
        passes = len(self._passes())
        # arrival times keep the unshuffled clock (a minute between passes): strictly increasing
        lengths = [len(self.pass_positions(p)) for p in range(passes)]
        starts = np.concatenate([[0.0], np.cumsum([m * dt + 60.0 for m in lengths])])
        arrival = [starts[p] + k * dt for p in range(passes) for k in range(lengths[p])]
        c = self.config
        logger.info(
            "rendering %d passes of %d frames (%s mode) on a %g m route, world seed %d",
            passes, n, c.mode, c.route_length_m, c.seed,
        )
        for index, (pass_number, k) in enumerate(self.schedule()):
            yield self.frame_at(pass_number, k, index, arrival[index])

    def frame_at(self, pass_number: int, k: int, index: int = 0, timestamp: float = 0.0) -> Frame:
        """Frame ``k`` of pass ``pass_number``, rendered on its own (random access, e.g. for benchmarks)."""
        c = self.config
        camera = self.camera
        n = c.frames_per_traversal
        traversal, illumination, lateral, yaw, occluders = self._passes()[pass_number]
        # a reversed pass keeps the camera facing the route's forward direction (a vehicle backing
        # up, or the recording played backwards): views facing the other way are another problem
        along = float(self.pass_positions(pass_number)[k]) * self.step_m
        pose = self.world.pose_at(along, lateral, yaw)
        place = pass_number * n + k
        image, depth = self.world.render(
            pose, camera.matrix, camera.width, camera.height, Lighting.of(illumination),
            occluders_at(c.seed + pass_number, along / c.speed_mps, self.world.route, occluders),
            noise_std=c.noise_std, noise_seed=c.seed * 1_000_003 + place, max_depth_m=c.max_depth_m,
        )
        sequence_index = k if traversal != "stream" else place
        return Frame(
            index=index, timestamp=timestamp, image=image, traversal=traversal, sequence_index=sequence_index,
            name=f"{traversal}-{sequence_index:05d}", depth=depth, camera=camera, pose=pose,
        )

    def loop_ground_truth(self) -> LoopGroundTruth:
        c = self.config
        n = c.frames_per_traversal
        if c.mode == "paired":
            return self._paired_truth(c.tolerance)
        schedule = self.schedule()
        # stream: a frame revisits every frame given before it within the radius along the
        # (closed) route that it reached by driving at least half the route since: frames of
        # earlier laps, and the start of its own lap when the lap closes. In a shuffled
        # stream every frame given before it at that place counts: it was not just there.
        reach = int(np.floor(c.revisit_radius_m / self.step_m))
        ks = np.array([int(round(self.pass_positions(p)[k])) for p, k in schedule], dtype=np.int64)
        rows = []
        for frame in range(len(schedule)):
            gap = np.abs(ks[:frame] - ks[frame])
            near = np.minimum(gap, n - gap) <= reach
            if not c.shuffle:
                near &= frame - np.arange(frame) >= n / 2
            rows.append(np.flatnonzero(near).astype(np.int64))
        return LoopGroundTruth.from_rows(np.arange(len(schedule)), rows)

    def loop_ground_truth_at(self, tolerance: int) -> LoopGroundTruth | None:
        """Paired mode only: stream revisits are defined by ``revisit_radius_m``, not zeta."""
        return self._paired_truth(tolerance) if self.config.mode == "paired" else None

    def _paired_truth(self, tolerance: int) -> LoopGroundTruth:
        n = self.config.frames_per_traversal
        positions = self.pass_positions(1)
        queries = np.arange(n, n + len(positions))
        places = np.array([int(round(positions[k])) for _, k in self.schedule()[n:]], dtype=np.int64)
        return LoopGroundTruth.band(queries, places, tolerance, valid=(0, n - 1))
