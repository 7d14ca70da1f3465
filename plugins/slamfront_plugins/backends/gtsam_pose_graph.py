"""The ``gtsam_pose_graph`` back end: odometry and verified loop closures -> optimised trajectory."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import Backend, Camera, DataError, Frame, Plugin, PluginConfig, PluginError, StageInputs
from slamfront.core import geometry
from slamfront.core.errors import CoreError
from slamfront.core.posegraph import PoseGraph, make_graph
from slamfront.data import DataPath
from slamfront.local_features import LocalFeatureExtractor
from slamfront.matching import Matcher, resolve_max_distance
from slamfront.messages import Features, LoopResult, Message, RelativePose, Trajectory
from slamfront.posegraph.io import OdometryTable, read_odometry
from slamfront.posegraph.solver import (
    Isam2Session,
    SolverOptions,
    edge_factors,
    objective,
    optimize,
    prior_factor,
)
from slamfront_plugins.backends.messages import LoopConstraint, PoseGraphState
from slamfront_plugins.backends.pnp_verification import FrameFeatures, PnPConfig, lift, verify


class Sigmas(PluginConfig):
    """Standard deviations of a relative pose, per axis."""

    translation_m: float = Field(0.05, ge=0, description="translation standard deviation, metres")
    rotation_deg: float = Field(1.0, ge=0, description="rotation standard deviation, degrees")

    def information(self) -> np.ndarray:
        """(6, 6) diagonal information, translation first; zero sigmas are floored (1 mm, 0.01 deg)."""
        translation = max(self.translation_m, 1e-3)
        rotation = np.deg2rad(max(self.rotation_deg, 1e-2))
        return np.diag([translation**-2] * 3 + [rotation**-2] * 3)


class GtsamPoseGraph(Backend):
    """A GTSAM pose graph over the run's frames: odometry edges between consecutive frames
    and an edge for each loop closure whose relative pose was verified.

    Odometry comes from the source's ground-truth poses with seeded noise, from a file
    (trajectory, graph or run log), from ``RelativePose`` messages of earlier stages
    (registration, localizer) or from the images themselves: frame-to-frame PnP on the
    local features this back end keeps for loop verification (``odometry: pnp``; a
    frame PnP cannot place repeats the previous motion, with little weight). A loop
    closure the detector accepts gets its relative pose from an earlier stage's
    ``RelativePose`` between the two frames or from this back end's own PnP on the
    matched frame's depth; without one it is logged as skipped, never added as an
    identity. Detectors that answer for earlier frames (sequence detectors) are
    verified between the frame answered and its match. ``solver`` picks batch
    Levenberg-Marquardt (at the end of the run) or iSAM2 (updated every frame), robust
    kernels and GNC.
    """

    name = "gtsam_pose_graph"
    reads_pixels = True  # its own PnP verification extracts features and lifts them with depth

    class Config(PluginConfig):
        odometry: Literal["ground_truth", "file", "stages", "pnp"] = Field(
            "ground_truth",
            description="ground truth + noise, a file, RelativePose messages of earlier stages, or frame-to-frame "
            "PnP on the images (this back end's features, lifted with the previous frame's depth)",
        )
        odometry_file: DataPath | None = Field(
            None, description="odometry: file -- TUM/x-y-theta/KITTI trajectory, g2o/iSAM graph, or a run.mcap"
        )
        odometry_noise: Sigmas = Field(
            default_factory=lambda: Sigmas(translation_m=0.02, rotation_deg=0.5),
            description="noise added to ground-truth odometry (per axis, seeded)",
        )
        odometry_sigmas: Sigmas | None = Field(
            None, description="odometry edges' standard deviations in the graph (default: odometry_noise)"
        )
        seed: int = Field(0, description="seed of the odometry noise")
        odometry_max_disagreement: float = Field(
            0.5, ge=0,
            description="odometry: pnp -- PnP is also solved backwards (this frame's points into the previous "
            "image); a motion whose two solutions differ by more than this fraction of its length is refused "
            "(a wrong solution on repeated texture rarely agrees with its reverse)",
        )
        odometry_max_disagreement_deg: float = Field(
            5.0, ge=0, description="odometry: pnp -- ... or whose rotations differ by more than this, degrees"
        )
        odometry_fallback_sigmas: Sigmas = Field(
            default_factory=lambda: Sigmas(translation_m=1.0, rotation_deg=10.0),
            description="odometry: pnp -- standard deviations of the previous motion repeated for a frame that PnP "
            "could not place (weak: the graph stays connected without trusting the guess)",
        )
        loop_sigmas: Sigmas = Field(
            default_factory=lambda: Sigmas(translation_m=0.1, rotation_deg=2.0),
            description="loop-closure edges' standard deviations (when their message gives no information)",
        )
        loop_pose: Literal["auto", "stages", "pnp"] = Field(
            "auto", description="a loop closure's relative pose: from an earlier stage's RelativePose (stages), "
            "this back end's PnP on depth (pnp), or the first of these that exists (auto)",
        )
        stage_loops: bool = Field(
            True, description="add RelativePose messages of earlier stages between non-consecutive frames as loops"
        )
        pnp: PnPConfig = Field(default_factory=PnPConfig, description="PnP verification settings")
        solver: SolverOptions = Field(default_factory=SolverOptions, description="mode, kernel, GNC, iSAM2 settings")

        @model_validator(mode="after")
        def _file_given(self) -> GtsamPoseGraph.Config:
            if self.odometry == "file" and self.odometry_file is None:
                raise ValueError("odometry: file needs odometry_file")
            return self

    @classmethod
    def reads_pixels_with(cls, config: PluginConfig) -> bool:
        # loop poses taken only from earlier stages' RelativePose and odometry not by PnP: no pixels
        return getattr(config, "loop_pose", "auto") != "stages" or getattr(config, "odometry", "") == "pnp"

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self.config: GtsamPoseGraph.Config
        self._rng = np.random.default_rng(self.config.seed)
        self._frames: list[int] = []
        self._initial: list[np.ndarray] = []
        self._edges: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        self._features: dict[int, FrameFeatures] = {}
        self._matcher: Matcher | None = None
        self._stage_descriptor: str | None = None
        """The descriptor stage's local-feature type, when it gives local features to reuse."""
        self._previous: Frame | None = None
        self._isam: Isam2Session | None = None
        self._motion = np.eye(4)
        """The last odometry motion (odometry: pnp repeats it when PnP fails)."""
        self._counts = {"n_loop_closures_added": 0, "n_loop_closures_skipped": 0}
        if self.config.odometry == "pnp":
            self._counts["n_odometry_fallbacks"] = 0
        self._result: dict[str, float | int | str | bool] = {}

    @cached_property
    def _extractor(self) -> LocalFeatureExtractor:
        return LocalFeatureExtractor(self.config.pnp.descriptor, max_features=self.config.pnp.n_features)

    @cached_property
    def _odometry_table(self) -> OdometryTable:
        assert self.config.odometry_file is not None
        return read_odometry(self.config.odometry_file)

    def check(self, stages: Mapping[str, Plugin]) -> None:
        descriptor = stages.get("descriptor")
        if descriptor is not None and getattr(descriptor, "produces_local", False):
            self._stage_descriptor = getattr(descriptor.config, "descriptor", None)
        if self.config.odometry == "stages" and not {"registration", "localizer"} & set(stages):
            raise PluginError(
                "gtsam_pose_graph: odometry: stages needs a registration or localizer stage producing RelativePose"
            )
        if self.config.odometry == "file":
            self._odometry_table  # noqa: B018 (read the file now: a bad file fails before the first frame)

    # --- per frame ----------------------------------------------------------------------

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        frame = inputs.frame
        relative = [m for kind in inputs.outputs for m in inputs.outputs[kind] if isinstance(m, RelativePose)]
        first_edge = len(self._edges)
        self._remember_features(frame, inputs)
        messages: list[Message] = []
        if self._previous is None:
            pose = frame.pose if frame.pose is not None and self.config.odometry == "ground_truth" else np.eye(4)
        else:
            motion, information, odometry_message = self._odometry(frame, relative)
            self._edges.append((self._previous.index, frame.index, motion, information))
            self._motion = motion
            pose = self._initial[-1] @ motion
            messages += [odometry_message] if odometry_message is not None else []
        self._frames.append(frame.index)
        self._initial.append(np.asarray(pose, dtype=np.float64))
        for outcome in inputs.outputs.get("loop_detector", []):
            if isinstance(outcome, LoopResult) and outcome.accepted and outcome.match >= 0:
                messages.append(self._close_loop(frame, outcome.frame, outcome.match, relative))
        if self.config.stage_loops:
            messages += self._stage_loops(frame, relative)
        self._previous = frame
        if self.config.solver.mode == "isam2":
            messages += self._isam2_update(frame.index, first_edge)
        return messages

    def _odometry(
        self, frame: Frame, relative: list[RelativePose]
    ) -> tuple[np.ndarray, np.ndarray, RelativePose | None]:
        """The motion from the previous frame, its information, and (odometry: pnp) the
        RelativePose message saying how it was measured."""
        assert self._previous is not None
        previous = self._previous
        sigmas = self.config.odometry_sigmas or self.config.odometry_noise
        if self.config.odometry == "pnp":
            return self._pnp_odometry(previous, frame, sigmas)
        motion, information = self._given_odometry(previous, frame, relative, sigmas)
        return motion, information, None

    def _pnp_odometry(self, previous: Frame, frame: Frame, sigmas: Sigmas) -> tuple[np.ndarray, np.ndarray, RelativePose]:
        reference, query = self._features.get(previous.index), self._features.get(frame.index)
        if reference is None or query is None or frame.camera is None:
            raise DataError(f"frame {frame.index}: odometry: pnp needs frames with a camera and depth")
        assert self._matcher is not None
        verdict = verify(reference, query, frame.camera, self._matcher, self.config.pnp)
        problem = verdict.reason if verdict.transform is None else self._disagreement(reference, query, frame.camera,
                                                                                      verdict.transform)
        if problem is None:
            information = sigmas.information()
            return verdict.transform, information, RelativePose(
                previous.index, frame.index, verdict.transform, information=information,
                method="pnp odometry", inliers=verdict.inliers,
            )
        self._counts["n_odometry_fallbacks"] += 1
        information = self.config.odometry_fallback_sigmas.information()
        return self._motion, information, RelativePose(
            previous.index, frame.index, self._motion, information=information,
            method=f"previous motion ({problem})", inliers=verdict.inliers,
        )

    def _disagreement(
        self, reference: FrameFeatures, query: FrameFeatures, camera: Camera, forward: np.ndarray
    ) -> str | None:
        """Why the forward PnP motion is not trusted (its reverse fails or disagrees), or None."""
        assert self._matcher is not None
        backward = verify(query, reference, camera, self._matcher, self.config.pnp)
        if backward.transform is None:
            return f"backward {backward.reason}"
        gap = forward @ backward.transform  # the identity when both agree
        metres, degrees = float(np.linalg.norm(gap[:3, 3])), geometry.rotation_angle_deg(gap)
        length = float(np.linalg.norm(forward[:3, 3]))
        if metres > self.config.odometry_max_disagreement * length or degrees > self.config.odometry_max_disagreement_deg:
            return f"forward and backward PnP differ by {metres:.2f} m and {degrees:.1f} deg over {length:.2f} m"
        return None

    def _given_odometry(
        self, previous: Frame, frame: Frame, relative: list[RelativePose], sigmas: Sigmas
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.config.odometry == "ground_truth":
            if previous.pose is None or frame.pose is None:
                raise DataError(
                    f"frame {frame.index} has no ground-truth pose: odometry: ground_truth needs a source with poses"
                )
            noise = self._rng.normal(size=6) * np.r_[
                [self.config.odometry_noise.translation_m] * 3, [np.deg2rad(self.config.odometry_noise.rotation_deg)] * 3
            ]
            return geometry.relative(previous.pose, frame.pose) @ geometry.exp_se3(noise), sigmas.information()
        if self.config.odometry == "file":
            motion, information = self._odometry_table.between(
                (previous.index, previous.timestamp), (frame.index, frame.timestamp)
            )
            return motion, sigmas.information() if information is None else information
        for message in relative:
            if (message.frame_from, message.frame_to) == (previous.index, frame.index):
                info = sigmas.information() if message.information is None else message.information
                return message.transform, info
        raise DataError(
            f"frame {frame.index}: odometry: stages, but no earlier stage gave a RelativePose from frame "
            f"{previous.index} to {frame.index}"
        )

    def _remember_features(self, frame: Frame, inputs: StageInputs) -> None:
        """Keep the frame's features (and their 3-D points) for loops closed later and PnP odometry."""
        if (self.config.loop_pose == "stages" and self.config.odometry != "pnp") or frame.camera is None:
            return
        stage = self._stage_descriptor
        features = next((m for m in inputs.outputs.get("descriptor", []) if isinstance(m, Features)), None)
        if stage is not None and features is not None and features.keypoints is not None:
            keypoints, descriptors, metric, kind = features.keypoints, features.descriptors, features.metric, stage
        else:
            grey = frame.gray()
            own = self._extractor.extract(grey)
            keypoints, descriptors, metric, kind = own.keypoints, own.descriptors, own.metric, self.config.pnp.descriptor
        if self._matcher is None:
            matching = self.config.pnp.matching
            self._matcher = Matcher(matching, metric, resolve_max_distance(matching, kind))
        self._features[frame.index] = FrameFeatures(keypoints, descriptors, lift(keypoints, frame.depth, frame.camera))

    def _close_loop(self, frame: Frame, query: int, match: int, relative: list[RelativePose]) -> LoopConstraint:
        """Verify that frame ``query`` (``frame``, or an earlier one a sequence detector answers
        for now) closes a loop with frame ``match``, and add the edge when it does."""
        transform, information, inliers, reason = None, self.config.loop_sigmas.information(), 0, ""
        if self.config.loop_pose in ("auto", "stages"):
            for message in relative:
                if {message.frame_from, message.frame_to} == {match, query}:
                    forward = message.frame_from == match
                    transform = message.transform if forward else geometry.invert(message.transform)
                    if message.information is not None and forward:
                        information = message.information
                    inliers, reason = message.inliers, f"{message.method or 'stage'} relative pose"
            if transform is None:
                reason = "no earlier stage gave a relative pose"
        if transform is None and self.config.loop_pose in ("auto", "pnp"):
            older, newer = self._features.get(match), self._features.get(query)
            if older is None or newer is None or frame.camera is None:
                reason = f"frame {match} has no features and depth for PnP"
            else:
                assert self._matcher is not None
                verdict = verify(older, newer, frame.camera, self._matcher, self.config.pnp)
                transform, inliers, reason = verdict.transform, verdict.inliers, verdict.reason
        if transform is None:
            self._counts["n_loop_closures_skipped"] += 1
            return LoopConstraint(frame=query, match=match, added=False, reason=f"not verified: {reason}")
        self._edges.append((match, query, transform, information))
        self._counts["n_loop_closures_added"] += 1
        return LoopConstraint(frame=query, match=match, added=True, reason=reason, transform=transform, inliers=inliers)

    def _stage_loops(self, frame: Frame, relative: list[RelativePose]) -> list[Message]:
        """RelativePose messages between this frame and a non-adjacent earlier one that no
        LoopResult asked for (a registration stage may find loops by itself)."""
        # odometry (consecutive frames) is the common case: only a candidate loop pays for the sets
        candidates = [m for m in relative if frame.index in (m.frame_from, m.frame_to) and abs(m.frame_from - m.frame_to) != 1]
        if not candidates:
            return []
        known = {frozenset((s, t)) for s, t, _, _ in self._edges}
        frames = set(self._frames)
        added: list[Message] = []
        for message in candidates:
            pair = (message.frame_from, message.frame_to)
            if frozenset(pair) in known or not set(pair) <= frames:
                continue
            info = self.config.loop_sigmas.information() if message.information is None else message.information
            self._edges.append((*pair, message.transform, info))
            self._counts["n_loop_closures_added"] += 1
            added.append(LoopConstraint(
                frame=frame.index, match=min(pair) if max(pair) == frame.index else max(pair), added=True,
                reason=f"{message.method or 'stage'} relative pose", transform=message.transform,
                inliers=message.inliers,
            ))
        return added

    def _isam2_update(self, index: int, first_edge: int) -> list[Message]:
        options = self.config.solver
        if self._isam is None:
            self._isam = Isam2Session(3, options)
        new_edges = self._edges[first_edge:]
        sources = np.array([e[0] for e in new_edges], dtype=np.int64)
        targets = np.array([e[1] for e in new_edges], dtype=np.int64)
        loops = np.abs(targets - sources) != 1
        factors = edge_factors(
            3, sources, targets, np.array([e[2] for e in new_edges]).reshape(-1, 4, 4),
            np.array([e[3] for e in new_edges]).reshape(-1, 6, 6),
            np.ones(len(new_edges), dtype=bool) if options.robust_odometry else loops, self._isam.kernel,
        )
        if len(self._frames) == 1:
            guess = self._initial[0]
            factors.append(prior_factor(3, index, guess))
        else:
            odometry = next(e for e in new_edges if e[1] == index and e[0] == self._frames[-2])
            guess = self._isam.pose(self._frames[-2]) @ odometry[2]
        self._isam.update(factors, {index: guess})
        if not loops.any():
            return []
        return [Trajectory(label="isam2", frames=np.array(self._frames, dtype=np.int64), poses=self._isam.estimate())]

    # --- at the end ---------------------------------------------------------------------

    def graph(self) -> PoseGraph:
        """The graph built so far (vertices are frame indices)."""
        try:
            return make_graph(
                dim=3,
                ids=np.array(self._frames, dtype=np.int64),
                poses=np.array(self._initial).reshape(-1, 4, 4),
                sources=np.array([e[0] for e in self._edges], dtype=np.int64),
                targets=np.array([e[1] for e in self._edges], dtype=np.int64),
                measurements=np.array([e[2] for e in self._edges]).reshape(-1, 4, 4),
                information=np.array([e[3] for e in self._edges]).reshape(-1, 6, 6),
                name=self.name,
            )
        except CoreError as exc:
            raise DataError(f"gtsam_pose_graph: {exc}") from None

    def finish(self) -> Sequence[Message]:
        if not self._frames:
            return []
        graph = self.graph()
        initial = graph.poses
        assert initial is not None
        options = self.config.solver
        if options.mode == "isam2" and self._isam is not None:
            self._isam.relinearize(options.isam2_final_updates)
            optimised = self._isam.estimate()
            self._result = {
                "cost_before": objective(graph, initial, options),
                "cost_after": objective(graph, optimised, options),
                "iterations": self._isam.updates,
                "converged": True,
            }
        else:
            result = optimize(graph, options)
            optimised = result.poses
            summary = result.summary()
            self._result = {key: summary[key] for key in ("cost_before", "cost_after", "iterations", "converged")}
            self._result["optimisation_seconds"] = result.seconds
            if "n_rejected_edges" in summary:  # GNC's edge weights
                self._result["n_rejected_edges"] = summary["n_rejected_edges"]
        frames = graph.ids
        return [
            Trajectory(label="odometry", frames=frames, poses=initial),
            Trajectory(label="optimised", frames=frames, poses=optimised),
            PoseGraphState.from_graph(graph, initial, optimised),
        ]

    def statistics(self) -> dict[str, float | int | str | bool]:
        loops = sum(1 for s, t, _, _ in self._edges if abs(t - s) != 1)
        return {
            "n_vertices": len(self._frames),
            "n_edges": len(self._edges),
            "n_graph_loop_closures": loops,
            **self._counts,
            "backend_mode": self.config.solver.mode,
            "backend_kernel": self.config.solver.kernel,
            **self._result,
        }
