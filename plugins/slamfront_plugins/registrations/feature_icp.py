"""The ``feature_icp`` registration: RGB-D frames to one global 3-D model (Barbosa 2017, 4.2)."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from slamfront import Frame, Registration, StageInputs
from slamfront.core.clouds import transform_points
from slamfront.core.geometry import invert
from slamfront.messages import LoopResult, Message, PointCloud, RelativePose
from slamfront_plugins.registrations.clouds import PreparedCloud, StepTimer, UnusableFrame, prepare_cloud
from slamfront_plugins.registrations.config import FeatureIcpConfig
from slamfront_plugins.registrations.messages import CloudRegistration, RegisteredTrajectory
from slamfront_plugins.registrations.model import ModelBuilder
from slamfront_plugins.registrations.pairwise import align
from slamfront_plugins.registrations.pose_graph import Link, refine

logger = logging.getLogger(__name__)

PRIOR_INFORMATION = (1e-2, 1e-2, 1e-2, 1e-1, 1e-1, 1e-1)
"""Information (x, y, z, rx, ry, rz) of a frame placed by the motion prior alone: sigma
10 m and about 180 degrees, so a back end keeps the graph connected without trusting it."""


class FeatureIcp(Registration):
    """RGB-D to a global model: outlier filter, voxel grid, normals, FPFH/PFH, RANSAC/FGR, ICP, chained.

    Each frame's depth becomes a cloud (intrinsics, truncation), filtered by statistical
    outlier removal, downsampled on a voxel grid, with normals oriented to the camera.
    FPFH (Open3D) or PFH (125 bins, PCL's layout) features feed an initial alignment by
    RANSAC on feature matches (the role of PCL's SAC-IA in the paper) or by Fast Global
    Registration; ICP (point-to-point or point-to-plane; the paper's 100 iterations, 0.05 m,
    epsilon 1e-9) refines it. Each cloud is aligned to the previous aligned one and the
    transforms are chained. An alignment failing the fitness / inlier-RMSE / motion
    check is retried by the fallbacks (wider search, previous motion); if all fail the
    frame is reported as rejected and kept out of the model. With ``pose_graph`` the
    chain is refined at the end with loop edges (nearby revisits, and matches a loop
    detector earlier in the recipe accepted). Outputs per frame: ``CloudRegistration``
    (pose, fitness, RMSE, time per step) and the aligned cloud; at the end the final
    trajectory and the model (``PointCloud`` role ``model``, written as ``model.ply``).
    """

    name = "feature_icp"
    version = "0.1.0"
    Config = FeatureIcpConfig
    config: FeatureIcpConfig

    def __init__(self, config: FeatureIcpConfig | None = None) -> None:
        super().__init__(config)
        c = self.config
        self._poses: dict[int, np.ndarray] = {}
        self._previous: int | None = None
        self._motion = np.eye(4)
        """Camera motion between the last two frames (for the constant-velocity guesses)."""
        self._target: PreparedCloud | None = None
        self._clouds: dict[int, PreparedCloud] = {}
        self._links: list[Link] = []
        self._suggested: set[tuple[int, int]] = set()
        self._model = ModelBuilder(c.model_voxel_m, keep_parts=c.pose_graph)
        self._last_frame = -1
        self._not_registered: list[int] = []

    # -- per frame -----------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        previous = self._previous
        messages = self._register(inputs)
        registration = next(m for m in messages if isinstance(m, CloudRegistration))
        if registration.outcome in ("rejected", "failed"):
            self._not_registered.append(registration.frame)
            logger.info("frame %d %s: %s; placed by the motion prior", registration.frame,
                        registration.outcome, registration.reason)
        return [*messages, *self._relative_poses(registration, previous)]

    def _relative_poses(self, registration: CloudRegistration, previous: int | None) -> list[RelativePose]:
        """The motion from the previous frame, for a back end (``odometry: stages``): the
        alignment when this frame was aligned to it; otherwise the placement by the motion
        prior, with little weight, and the alignment to an older frame if there was one."""
        if previous is None:
            return []
        frame = registration.frame
        method = f"registration {registration.method}"
        aligned = registration.outcome in ("aligned", "fallback") and registration.transform is not None
        if aligned and registration.target == previous:
            return [RelativePose(previous, frame, registration.transform, method=method,
                                 inliers=registration.n_correspondences)]
        # _place has just set _motion to this frame's pose relative to the previous one
        guessed = RelativePose(previous, frame, self._motion,
                               information=np.diag(PRIOR_INFORMATION), method="motion prior (not registered)")
        if not aligned:
            return [guessed]
        return [guessed, RelativePose(registration.target, frame, registration.transform, method=method,
                                      inliers=registration.n_correspondences)]

    def _register(self, inputs: StageInputs) -> list[Message]:
        frame = inputs.frame
        self._last_frame = frame.index
        self._note_loop_suggestions(inputs)
        timer = StepTimer()
        prior = self._prior_pose(frame)
        try:
            prepared = prepare_cloud(frame, self.config, timer)
        except UnusableFrame as exc:
            self._place(frame.index, prior)
            return [CloudRegistration(frame=frame.index, outcome="failed", pose=prior, reason=str(exc),
                                      seconds=timer.seconds)]
        if self._target is None:
            self._accept(prepared, prior, link=None)
            message = CloudRegistration(frame=frame.index, outcome="first", pose=prior, n_points=prepared.n_points,
                                        method="anchor", seconds=timer.seconds)
            return self._with_cloud(message, prepared)
        target = self._target
        target_pose = self._poses[target.frame]
        guess = invert(target_pose) @ prior
        motion_guess = invert(target_pose) @ self._poses[self._previous] @ self._motion
        seed = self.config.seed * 1_000_003 + frame.index
        alignment, attempts = align(prepared, target, guess, motion_guess, self.config, timer, seed)
        common = dict(
            frame=frame.index, target=target.frame, transform=alignment.transform, fitness=alignment.fitness,
            inlier_rmse=alignment.inlier_rmse, n_points=prepared.n_points,
            n_correspondences=alignment.n_correspondences, method=alignment.method, seconds=timer.seconds,
        )
        if not alignment.passed:
            self._place(frame.index, prior)
            reason = "; ".join(f"{a.method}: {a.problem}" for a in attempts)
            return [CloudRegistration(outcome="rejected", pose=prior, reason=reason, **common)]
        pose = target_pose @ alignment.transform
        self._accept(prepared, pose, Link(frame.index, target.frame, alignment.transform))
        first = attempts[0]
        if alignment is first:
            outcome, reason = "aligned", ""
        else:
            outcome = "fallback"
            reason = first.problem or (
                f"{first.method}: fitness {first.fitness:.3f} below confident_fitness "
                f"{self.config.confident_fitness:g}; {alignment.method} fits better ({alignment.fitness:.3f})"
            )
        return self._with_cloud(CloudRegistration(outcome=outcome, pose=pose, reason=reason, **common), prepared)

    def _prior_pose(self, frame: Frame) -> np.ndarray:
        """Where the camera probably is before registering: the motion prior."""
        if self._previous is None:
            if self.config.start_pose == "ground_truth" and frame.pose is not None:
                return np.asarray(frame.pose, dtype=np.float64)
            return np.eye(4)
        previous = self._poses[self._previous]
        return previous @ self._motion if self.config.motion_prior == "constant_velocity" else previous.copy()

    def _place(self, frame: int, pose: np.ndarray) -> None:
        if self._previous is not None:
            self._motion = invert(self._poses[self._previous]) @ pose
        self._poses[frame] = pose
        self._previous = frame

    def _accept(self, prepared: PreparedCloud, pose: np.ndarray, link: Link | None) -> None:
        self._place(prepared.frame, pose)
        self._target = prepared
        if link is not None:
            self._links.append(link)
        if self.config.pose_graph:
            self._clouds[prepared.frame] = prepared
        self._model.add(prepared.frame, prepared.model_points, prepared.model_colors, pose)

    def _with_cloud(self, message: CloudRegistration, prepared: PreparedCloud) -> list[Message]:
        if not self.config.log_clouds:
            return [message]
        points = transform_points(message.pose, np.asarray(prepared.cloud.points)).astype(np.float32)
        colors = np.round(np.asarray(prepared.cloud.colors) * 255.0).astype(np.uint8)
        return [message, PointCloud(frame=message.frame, role="aligned", points=points, colors=colors)]

    def _note_loop_suggestions(self, inputs: StageInputs) -> None:
        for result in inputs.outputs.get("loop_detector", ()):
            if isinstance(result, LoopResult) and result.accepted and 0 <= result.match != result.frame:
                self._suggested.add((min(result.match, result.frame), max(result.match, result.frame)))

    # -- end of run -------------------------------------------------------------------------

    def finish(self) -> Sequence[Message]:
        if self._not_registered:
            # once per run, so it reaches the terminal without flooding it
            logger.warning(
                "%d of %d frames could not be registered and were placed by the motion prior (first: frame %d); "
                "see /registration/cloud_registration for why",
                len(self._not_registered), len(self._poses), self._not_registered[0],
            )
        timer = StepTimer()
        poses, refined, loops = self._poses, False, np.empty((0, 2), dtype=np.int64)
        if self.config.pose_graph and len(self._clouds) > 2:
            refinement = refine(self._clouds, self._poses, self._links, self.config, timer, self._suggested)
            poses, refined, loops = refinement.poses, refinement.refined, refinement.loop_edges
        points, colors = timer.run("model", lambda: self._model.build(poses))
        frames = np.array(sorted(poses), dtype=np.int64)
        stacked = np.stack([poses[int(f)] for f in frames]) if len(frames) else np.empty((0, 4, 4))
        return [
            RegisteredTrajectory(frames=frames, poses=stacked, refined=refined, loop_edges=loops,
                                 seconds=timer.seconds),
            PointCloud(frame=self._last_frame, role="model", points=points, colors=colors),
        ]
