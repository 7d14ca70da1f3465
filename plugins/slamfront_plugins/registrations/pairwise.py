"""Aligning one cloud to another: initial alignment, ICP, a quality check and fallbacks.

The initial alignment plays SAC-IA's role (Barbosa 2017, 2.2.3.4): RANSAC on feature
correspondences (Open3D's, with the edge-length and distance pre-checks that reject
bad samples early), or Fast Global Registration. ICP then refines it with the paper's
stopping rules. An alignment whose inlier fraction (fitness) is too small, whose inlier
RMSE is too large, or whose motion exceeds the configured limits is rejected, and the
configured fallbacks are tried in order instead of silently corrupting the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamfront.core.distances import nearest_two
from slamfront.core.geometry import rotation_angle_deg
from slamfront.lazy import lazy_module
from slamfront_plugins.registrations.clouds import PreparedCloud, StepTimer, open3d_threads
from slamfront_plugins.registrations.config import FeatureIcpConfig

o3d = lazy_module("open3d")  # loads on first use: listing plugins does not import it



@dataclass(frozen=True)
class Alignment:
    """One attempt's result: source camera -> target camera, with its quality."""

    transform: np.ndarray
    fitness: float
    inlier_rmse: float
    n_correspondences: int
    method: str
    problem: str = ""
    """Why the quality check rejected it ("" when it passed)."""

    @property
    def passed(self) -> bool:
        return not self.problem


def quiet() -> o3d.utility.VerbosityContextManager:
    """Silence Open3D's console warnings (results and failures are reported instead)."""
    return o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error)


MUTUAL_MIN_RATIO = 0.1
"""Open3D's rule: mutual matches are used only if at least this fraction of points has one."""


def feature_matches(source: PreparedCloud, target: PreparedCloud, mutual: bool) -> np.ndarray:
    """(K, 2) int32 (source point, target point) pairs of nearest features.

    As Open3D's ``correspondences_from_features`` (every source point's nearest target
    feature; with ``mutual``, only pairs that are each other's nearest, unless fewer
    than 10 % of points have one), by the shared brute-force search (``nearest_two``), several
    times faster than its k-d tree in 33 or 125 dimensions.
    """
    source_features = np.asarray(source.features.data).T
    target_features = np.asarray(target.features.data).T
    forward = nearest_two(source_features, target_features, "l2")[2]
    pairs = np.stack([np.arange(len(forward)), forward], axis=1)
    if mutual:
        backward = nearest_two(target_features, source_features, "l2")[2]
        kept = pairs[backward[forward] == pairs[:, 0]]
        if len(kept) >= MUTUAL_MIN_RATIO * len(pairs):
            pairs = kept
    return pairs.astype(np.int32)


def initial_transform(
    source: PreparedCloud,
    target: PreparedCloud,
    pairs: np.ndarray,
    config: FeatureIcpConfig,
    seed: int,
    scale: float = 1.0,
) -> np.ndarray:
    """RANSAC or FGR on feature matches ``pairs``; ``scale`` widens distances and iterations."""
    voxel = config.voxel_size_m
    matches = o3d.utility.Vector2iVector(pairs)
    o3d.utility.random.seed(seed)  # both sample at random: seeded per pair, reproducible
    if config.initial_alignment == "fgr":
        option = o3d.pipelines.registration.FastGlobalRegistrationOption(
            maximum_correspondence_distance=config.fgr_distance_voxels * voxel * scale,
            iteration_number=int(config.fgr_iterations * scale),
        )
        with quiet():
            result = o3d.pipelines.registration.registration_fgr_based_on_correspondence(source.cloud, target.cloud, matches, option)
        return np.asarray(result.transformation)
    distance = config.ransac_distance_voxels * voxel * scale
    with quiet():
        result = o3d.pipelines.registration.registration_ransac_based_on_correspondence(
            source.cloud, target.cloud, matches, distance,
            o3d.pipelines.registration.TransformationEstimationPointToPoint(False), 3,
            [
                o3d.pipelines.registration.CorrespondenceCheckerBasedOnEdgeLength(config.ransac_edge_length_ratio),
                o3d.pipelines.registration.CorrespondenceCheckerBasedOnDistance(distance),
            ],
            o3d.pipelines.registration.RANSACConvergenceCriteria(int(config.ransac_max_iterations * scale), config.ransac_confidence),
        )
    return np.asarray(result.transformation)


def icp(
    source: PreparedCloud, target: PreparedCloud, start: np.ndarray, config: FeatureIcpConfig, distance: float
) -> o3d.pipelines.registration.RegistrationResult:
    """ICP with the paper's stopping rules (iterations, and epsilon on fitness and RMSE change).

    PCL stops on the change of the transform; Open3D on the relative change of fitness
    and inlier RMSE, which is the nearest equivalent it offers.
    """
    estimation = (
        o3d.pipelines.registration.TransformationEstimationPointToPlane()
        if config.icp_method == "point_to_plane"
        else o3d.pipelines.registration.TransformationEstimationPointToPoint(False)
    )
    criteria = o3d.pipelines.registration.ICPConvergenceCriteria(
        relative_fitness=config.icp_epsilon, relative_rmse=config.icp_epsilon, max_iteration=config.icp_max_iterations
    )
    with quiet():
        return o3d.pipelines.registration.registration_icp(source.cloud, target.cloud, distance, start, estimation, criteria)


def quality_problem(result: o3d.pipelines.registration.RegistrationResult, config: FeatureIcpConfig) -> str:
    """Why an ICP result is not trusted, or "" when it passes every check."""
    transform = np.asarray(result.transformation)
    if result.fitness <= 0:
        return f"fitness 0: no point within {config.icp_distance_m:g} m of the target after ICP"
    if result.fitness < config.min_fitness:
        return f"fitness {result.fitness:.3f} < min_fitness {config.min_fitness:g}"
    limit = config.max_inlier_rmse_ratio * config.icp_distance_m
    if result.inlier_rmse > limit:
        return (
            f"inlier RMSE {result.inlier_rmse:.4f} m > {limit:.4g} m "
            f"(max_inlier_rmse_ratio {config.max_inlier_rmse_ratio:g} of icp_distance_m)"
        )
    moved = float(np.linalg.norm(transform[:3, 3]))
    if config.max_translation_m is not None and moved > config.max_translation_m:
        return f"translation {moved:.3f} m > max_translation_m {config.max_translation_m:g}"
    turned = rotation_angle_deg(transform)
    if config.max_rotation_deg is not None and turned > config.max_rotation_deg:
        return f"rotation {turned:.1f} deg > max_rotation_deg {config.max_rotation_deg:g}"
    return ""


def _attempt(
    source: PreparedCloud,
    target: PreparedCloud,
    config: FeatureIcpConfig,
    timer: StepTimer,
    start: np.ndarray | None,
    matches: dict[str, np.ndarray],
    seed: int,
    scale: float,
    method: str,
) -> Alignment:
    """Initial alignment (when ``start`` is None), then ICP coarse-to-fine when ``scale`` > 1.

    ``matches`` caches the feature matches between attempts on the same pair.
    """
    if start is None:

        def initial() -> np.ndarray:
            if "pairs" not in matches:
                matches["pairs"] = feature_matches(source, target, config.mutual_filter)
            return initial_transform(source, target, matches["pairs"], config, seed, scale)

        start = timer.run("initial_alignment", initial)
    if scale > 1:
        start = np.asarray(
            timer.run("icp", lambda: icp(source, target, start, config, config.icp_distance_m * scale)).transformation
        )
    result = timer.run("icp", lambda: icp(source, target, start, config, config.icp_distance_m))
    return Alignment(
        transform=np.array(result.transformation),
        fitness=float(result.fitness),
        inlier_rmse=float(result.inlier_rmse),
        n_correspondences=len(result.correspondence_set),
        method=method,
        problem=quality_problem(result, config),
    )


def align(
    source: PreparedCloud,
    target: PreparedCloud,
    guess: np.ndarray,
    motion_guess: np.ndarray,
    config: FeatureIcpConfig,
    timer: StepTimer,
    seed: int,
) -> tuple[Alignment, list[Alignment]]:
    """Align ``source`` to ``target``: the configured attempt, then the fallbacks in order.

    An attempt that passes the check with a fitness of at least ``confident_fitness``
    ends the search. A lower one (little overlap, or a wrong alignment that still
    overlaps, like a slide along a corridor) gets a second opinion: the fallbacks run
    too and the best fit that passes wins.

    :param guess: source -> target transform from the motion prior (ICP alone starts here).
    :param motion_guess: source -> target transform if the previous motion repeated
        (the ``previous_motion`` fallback starts here).
    :returns: the chosen attempt (passing the check if any does, else the best fit)
        and every attempt made, in order.
    """
    features = config.initial_alignment != "none"
    name = f"{config.feature}+{config.initial_alignment}+icp" if features else "icp"
    plans: list[tuple[np.ndarray | None, float, str]] = [(None if features else guess, 1.0, name)]
    for fallback in config.fallbacks:
        if fallback == "wider":
            plans.append((None if features else guess, config.wider_factor, f"{name} (wider)"))
        else:
            plans.append((motion_guess, config.wider_factor, "previous motion+icp"))
    attempts: list[Alignment] = []
    matches: dict[str, np.ndarray] = {}
    for start, scale, method in plans:
        with open3d_threads(config.threads):
            attempts.append(_attempt(source, target, config, timer, start, matches, seed, scale, method))
        if attempts[-1].passed and attempts[-1].fitness >= config.confident_fitness:
            return attempts[-1], attempts
    passing = [a for a in attempts if a.passed]
    return max(passing or attempts, key=lambda a: a.fitness), attempts
