"""Refining a chain of registrations with loop edges (Open3D's pose graph).

Chaining pairwise transforms accumulates drift; when the camera comes back to a place,
registering the new cloud to the old one gives a loop edge that pulls the chain
together. Loop candidates are frames whose estimated cameras are close and look the
same way (and any match a loop detector earlier in the recipe accepted); each is
registered like a consecutive pair and kept only if it passes the same quality check.
The optimisation (Levenberg-Marquardt with line processes, Choi et al. 2015) may still
prune a loop edge it finds inconsistent.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from slamfront.core.geometry import invert, relative
from slamfront.lazy import lazy_module
from slamfront_plugins.registrations.clouds import PreparedCloud, StepTimer, open3d_threads
from slamfront_plugins.registrations.config import FeatureIcpConfig
from slamfront_plugins.registrations.pairwise import align, quiet

o3d = lazy_module("open3d")  # loads on first use: listing plugins does not import it



@dataclass(frozen=True)
class Link:
    """A registration edge: ``transform`` maps frame ``source``'s camera into frame ``target``'s."""

    source: int
    target: int
    transform: np.ndarray


@dataclass(frozen=True)
class Refinement:
    """What the pose graph did."""

    poses: dict[int, np.ndarray]
    loop_edges: np.ndarray
    """(M, 2) int64 (older frame, newer frame) loop edges the optimisation kept."""
    n_tried: int
    refined: bool


def loop_candidates(
    poses: dict[int, np.ndarray], config: FeatureIcpConfig, suggested: Iterable[tuple[int, int]] = ()
) -> list[tuple[int, int]]:
    """(older, newer) frame pairs worth a loop registration, closest first per newer frame."""
    frames = np.array(sorted(poses), dtype=np.int64)
    if len(frames) < 2:
        return []
    stacked = np.stack([poses[int(f)] for f in frames])
    positions, axes = stacked[:, :3, 3], stacked[:, :3, 2]
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    cos_angle = np.clip(axes @ axes.T, -1.0, 1.0)
    gap = frames[None, :] - frames[:, None]  # newer (column) minus older (row)
    near = (
        (gap >= config.loop_min_gap)
        & (distance <= config.loop_radius_m)
        & (np.degrees(np.arccos(cos_angle)) <= config.loop_max_angle_deg)
    )
    pairs: list[tuple[int, int]] = []
    for newer in range(len(frames)):
        older = np.flatnonzero(near[:, newer])
        for row in older[np.argsort(distance[older, newer], kind="stable")][: config.loop_max_per_frame]:
            pairs.append((int(frames[row]), int(frames[newer])))
    known = set(pairs)
    ordered = {(min(a, b), max(a, b)) for a, b in suggested if a != b and a in poses and b in poses}
    return pairs + sorted(ordered - known)


def refine(
    clouds: dict[int, PreparedCloud],
    poses: dict[int, np.ndarray],
    links: list[Link],
    config: FeatureIcpConfig,
    timer: StepTimer,
    suggested: Iterable[tuple[int, int]] = (),
) -> Refinement:
    """Register loop candidates and optimise the pose graph of the frames in ``clouds``."""
    frames = sorted(clouds)
    node = {frame: k for k, frame in enumerate(frames)}
    in_graph = {f: poses[f] for f in frames}
    candidates = loop_candidates(in_graph, config, suggested)
    loops: list[Link] = []
    loop_timer = StepTimer()
    for older, newer in candidates:
        guess = relative(poses[older], poses[newer])
        seed = config.seed * 1_000_003 + older * 7919 + newer
        alignment, _ = align(clouds[newer], clouds[older], guess, guess, config, loop_timer, seed)
        if alignment.passed:
            loops.append(Link(newer, older, alignment.transform))
    timer.seconds["loop_registration"] = sum(loop_timer.seconds.values())
    if not loops:
        return Refinement(dict(poses), np.empty((0, 2), dtype=np.int64), len(candidates), refined=False)

    def build() -> o3d.pipelines.registration.PoseGraph:
        graph = o3d.pipelines.registration.PoseGraph()
        for frame in frames:
            graph.nodes.append(o3d.pipelines.registration.PoseGraphNode(poses[frame]))
        for link, uncertain in [(link, False) for link in links if link.source in node and link.target in node] + [
            (link, True) for link in loops
        ]:
            information = o3d.pipelines.registration.get_information_matrix_from_point_clouds(
                clouds[link.source].cloud, clouds[link.target].cloud, config.icp_distance_m, link.transform
            )
            graph.edges.append(
                o3d.pipelines.registration.PoseGraphEdge(node[link.source], node[link.target], link.transform, information, uncertain=uncertain)
            )
        return graph

    with open3d_threads(config.threads):
        graph = timer.run("pose_graph", build)
    option = o3d.pipelines.registration.GlobalOptimizationOption(
        max_correspondence_distance=config.icp_distance_m,
        edge_prune_threshold=config.edge_prune_threshold,
        preference_loop_closure=config.loop_preference,
        reference_node=0,
    )
    with quiet(), open3d_threads(config.threads):
        timer.run(
            "pose_graph",
            lambda: o3d.pipelines.registration.global_optimization(
                graph, o3d.pipelines.registration.GlobalOptimizationLevenbergMarquardt(), o3d.pipelines.registration.GlobalOptimizationConvergenceCriteria(), option
            ),
        )
    kept = [(frames[e.target_node_id], frames[e.source_node_id]) for e in graph.edges if e.uncertain]
    refined = {frame: np.array(graph.nodes[node[frame]].pose) for frame in frames}
    # frames outside the graph (rejected or failed) keep their place relative to the
    # closest earlier frame in it
    for frame in sorted(set(poses) - set(frames)):
        anchors = [f for f in frames if f < frame]
        anchor = anchors[-1] if anchors else frames[0]
        refined[frame] = refined[anchor] @ invert(poses[anchor]) @ poses[frame]
    return Refinement(refined, np.array(kept, dtype=np.int64).reshape(-1, 2), len(candidates), refined=bool(kept))
