"""Optimising pose graphs with GTSAM: batch Levenberg-Marquardt, GNC, and iSAM2.

One :class:`SolverOptions` drives everything the ``gtsam_pose_graph`` back end and
``slamfront optimize`` do. Robust kernels are GTSAM m-estimators wrapped around each
edge's Gaussian noise model (``noiseModel.Robust``), applied to loop closures (and to
odometry only when asked: odometry is what a front end trusts most). GNC is GTSAM's
``GncLMOptimizer`` (Yang et al., RA-L 2020) with the odometry chain and the prior marked
as known inliers.

Keys are the graph's vertex ids. A prior on the first vertex (and on ``FIX`` vertices)
removes the gauge freedom; it does not move the optimum of anything else.
"""

from __future__ import annotations

import functools
import operator
import time
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from annotated_types import Ge, Gt, Lt

from slamfront.core import geometry
from slamfront.core.errors import CoreError
from slamfront.core.posegraph import PoseGraph, check_connected, initial_poses, spanning_tree
from slamfront.errors import DataError
from slamfront.lazy import lazy_module
from slamfront.posegraph.kernels import KERNELS, KernelName

gtsam = lazy_module("gtsam")  # loads on first use: listing plugins does not import it

_ROTATION_FIRST = np.array([3, 4, 5, 0, 1, 2])
"""GTSAM's Pose3 tangent is (rx, ry, rz, x, y, z); graphs store translation first."""

_PRIOR_SIGMA = 1e-4
"""Gauge prior on the first vertex: tight, but loose enough to keep the system well conditioned."""


# A dataclass checked when made (InvalidOption), not a pydantic model: pydantic's import and
# schema building cost `slamfront optimize` ~0.09 s of CPU, a seventh of a plain GTSAM run on
# sphere2500. Inside a back end's pydantic config, pydantic validates it all the same (the
# constraints are annotated_types, the field descriptions the attribute docstrings).
@dataclass(frozen=True)
class SolverOptions:
    """How to optimise a pose graph."""

    __pydantic_config__: ClassVar[dict[str, Any]] = {"extra": "forbid", "use_attribute_docstrings": True}

    mode: Literal["batch", "isam2"] = "batch"
    """batch Levenberg-Marquardt, or iSAM2 adding one vertex at a time"""
    kernel: KernelName = "none"
    """robust kernel on loop closures: none, huber, cauchy, dcs, geman_mcclure, tukey, welsch, or gnc
    (graduated non-convexity, batch only)"""
    kernel_parameter: Annotated[float, Gt(0)] | None = None
    """the kernel's threshold on the whitened residual (default: the kernel's usual value)"""
    robust_odometry: bool = False
    """apply the kernel to odometry edges too"""
    gnc_loss: Literal["tls", "gm"] = "tls"
    """GNC surrogate: truncated least squares or Geman-McClure"""
    gnc_warm_start: Literal["none", "dcs"] = "dcs"
    """start GNC from the initial poses (none) or from a DCS solution (dcs)"""
    gnc_probability: Annotated[float, Gt(0), Lt(1)] = 0.99
    """GNC inlier threshold: chi-square quantile of each edge's dimension"""
    gnc_step: Annotated[float, Gt(1)] = 2.0
    """GNC's factor on its control parameter per outer iteration"""
    gnc_inner_iterations: Annotated[int, Ge(1)] = 20
    """LM iterations per GNC outer iteration"""
    max_iterations: Annotated[int, Ge(1)] = 100
    """LM iteration limit"""
    relative_tolerance: Annotated[float, Gt(0)] = 1e-5
    """LM stops when the cost falls by less than this fraction"""
    absolute_tolerance: Annotated[float, Ge(0)] = 1e-5
    """... or by less than this"""
    isam2_relinearize_threshold: Annotated[float, Gt(0)] = 0.1
    """iSAM2 relinearises variables moving more"""
    isam2_relinearize_skip: Annotated[int, Ge(1)] = 10
    """iSAM2 checks relinearisation every this many updates"""
    isam2_final_updates: Annotated[int, Ge(0)] = 3
    """extra iSAM2 updates after the last vertex"""
    isam2_factorization: Literal["auto", "cholesky", "qr"] = "auto"
    """iSAM2's linear solver: Cholesky (fast), QR (slower, copes with ill-conditioned information), or auto:
    Cholesky, redone with QR when GTSAM finds the system indeterminate (a run's online session: QR)"""

    def __post_init__(self) -> None:
        for name, problem in _field_problems(self):
            raise InvalidOption(name, problem)
        if self.kernel == "gnc" and self.mode != "batch":
            raise ValueError("kernel gnc needs mode batch (GTSAM's GNC is a batch optimiser)")

    def parameter(self) -> float:
        """The kernel parameter in use."""
        if self.kernel_parameter is not None:
            return self.kernel_parameter
        return KERNELS[self.kernel].default_parameter if self.kernel in KERNELS else 0.0


class InvalidOption(ValueError):
    """A :class:`SolverOptions` field out of its range or choices (``field`` names it)."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}")
        self.field = field
        self.problem = problem


_BOUNDS = {  # annotated_types bound: (its attribute, pydantic's words, the test)
    Gt: ("gt", "greater than", operator.gt),
    Ge: ("ge", "greater than or equal to", operator.ge),
    Lt: ("lt", "less than", operator.lt),
}


@functools.cache
def _field_rules(cls: type) -> dict[str, tuple[tuple[Any, ...], list[Any]]]:
    """Per field: the Literal choices (or ()) and the annotated_types bounds of its type."""
    rules = {}
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        choices: tuple[Any, ...] = ()
        bounds: list[Any] = []
        for part in (hint, *typing.get_args(hint)):  # X, X | None, Annotated[X, ...]
            if typing.get_origin(part) is Literal:
                choices = typing.get_args(part)
            if typing.get_origin(part) is Annotated:
                bounds += [m for m in part.__metadata__ if type(m) in _BOUNDS]
        rules[name] = (choices, bounds)
    return rules


def _field_problems(options: object) -> list[tuple[str, str]]:
    """What pydantic would say about each field's value (in pydantic's words)."""
    problems = []
    for name, (choices, bounds) in _field_rules(type(options)).items():
        value = getattr(options, name)
        if choices and value not in choices:
            problems.append((name, f"Input should be {' or '.join(repr(c) for c in choices)}"))
        for bound in bounds if value is not None else ():
            attribute, words, holds = _BOUNDS[type(bound)]
            limit = getattr(bound, attribute)
            if not holds(value, limit):
                problems.append((name, f"Input should be {words} {limit}"))
    return problems


@dataclass
class OptimizationResult:
    """What an optimisation gave.

    :ivar poses: (N, d+1, d+1) optimised poses in the order of the graph's ids.
    :ivar initial: (N, d+1, d+1) the poses it started from.
    :ivar cost_before: GTSAM's objective (half the sum of squared whitened residuals,
        through the kernel) at the initial poses.
    :ivar cost_after: the same objective at the solution (for GNC: with GNC's weights).
    :ivar iterations: LM iterations (batch; for GNC those of the warm start and of a
        final LM over GNC's weights, as GTSAM's GNC does not report its own), or iSAM2
        updates.
    :ivar seconds: wall time of building the GTSAM problem and solving it (not of reading it).
    :ivar weights: (M,) GNC's final weight per edge (1 inlier, 0 outlier), else None.
    :ivar factorization: iSAM2's linear solver (``cholesky`` or ``qr``), else "".
    """

    poses: np.ndarray
    initial: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int
    seconds: float
    converged: bool
    mode: str
    kernel: str
    weights: np.ndarray | None = None
    factorization: str = ""

    def summary(self) -> dict[str, Any]:
        """The scalar results, for metrics.json."""
        summary: dict[str, Any] = {
            "cost_before": self.cost_before,
            "cost_after": self.cost_after,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "converged": self.converged,
            "mode": self.mode,
            "kernel": self.kernel,
        }
        if self.factorization:
            summary["isam2_factorization"] = self.factorization
        if self.weights is not None:
            summary["n_rejected_edges"] = int(np.sum(self.weights < 0.5))
        return summary


# --- conversions ----------------------------------------------------------------------


def to_gtsam_poses(matrices: np.ndarray) -> list[gtsam.Pose2] | list[gtsam.Pose3]:
    """(N, 3, 3) or (N, 4, 4) rigid transforms as GTSAM poses (rotations re-normalised)."""
    matrices = np.asarray(matrices, dtype=np.float64)
    if geometry.dimension_of(matrices) == 2:
        return [gtsam.Pose2(x, y, theta) for x, y, theta in geometry.se2_parameters(matrices).tolist()]
    translation, quaternion = np.ascontiguousarray(matrices[:, :3, 3]), geometry.quaternions_of(matrices)
    # rows of an array go to GTSAM as they are; gtsam.Point3 is a Python function making a new array
    return [
        gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), xyz)
        for xyz, (qx, qy, qz, qw) in zip(translation, quaternion.tolist())
    ]


def to_gtsam_pose(matrix: np.ndarray) -> gtsam.Pose2 | gtsam.Pose3:
    """One (3, 3) or (4, 4) rigid transform as a GTSAM pose."""
    return to_gtsam_poses(np.asarray(matrix)[None])[0]


def poses_from_values(values: gtsam.Values, dim: int) -> np.ndarray:
    """(N, d+1, d+1) poses of every key in ``values``, in key order."""
    if dim == 2:
        params = gtsam.utilities.extractPose2(values)
        return geometry.se2(params[:, 0], params[:, 1], params[:, 2])
    flat = gtsam.utilities.extractPose3(values)
    return geometry.se3(flat[:, 9:12], flat[:, :9].reshape(-1, 3, 3))


def to_values(ids: np.ndarray, poses: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    for key, pose in zip(ids.tolist(), to_gtsam_poses(poses)):
        values.insert(key, pose)
    return values


def _between(dim: int) -> Callable[..., Any]:
    return gtsam.BetweenFactorPose2 if dim == 2 else gtsam.BetweenFactorPose3


def prior_factor(dim: int, key: int, pose: np.ndarray) -> Any:
    """The gauge prior holding vertex ``key`` at ``pose``."""
    sigmas = np.full(3 if dim == 2 else 6, _PRIOR_SIGMA)
    factor = gtsam.PriorFactorPose2 if dim == 2 else gtsam.PriorFactorPose3
    return factor(key, to_gtsam_pose(pose), gtsam.noiseModel.Diagonal.Sigmas(sigmas))


@dataclass(frozen=True)
class FactorLayout:
    """Which factor index is what, in a graph built by :func:`build_factor_graph`."""

    n_edges: int
    n_priors: int

    @property
    def prior_indices(self) -> list[int]:
        return list(range(self.n_edges, self.n_edges + self.n_priors))


def edge_factors(
    dim: int,
    sources: np.ndarray,
    targets: np.ndarray,
    measurements: np.ndarray,
    information: np.ndarray,
    robust: np.ndarray,
    kernel: Any | None,
) -> list[Any]:
    """GTSAM between-factors for edges; ``robust`` (M,) bool picks those wrapped in ``kernel``."""
    between = _between(dim)
    if not len(measurements):
        return []
    # one noise model per distinct information matrix (M3500 has 3, city10000 1; sphere2500
    # 4949): GTSAM's models are immutable, and each costs a Cholesky to build
    if dim == 3:  # graphs store translation first, GTSAM's Pose3 tangent is rotation first
        information = information[:, _ROTATION_FIRST][:, :, _ROTATION_FIRST]
    information = np.ascontiguousarray(information, dtype=np.float64)
    models: dict[tuple[bytes, bool], Any] = {}
    noises = []
    for matrix, wrap in zip(information, (robust & (kernel is not None)).tolist()):
        key = (matrix.tobytes(), wrap)
        noise = models.get(key)
        if noise is None:
            noise = gtsam.noiseModel.Gaussian.Information(matrix)
            if wrap:
                noise = gtsam.noiseModel.Robust.Create(kernel, noise)
            models[key] = noise
        noises.append(noise)
    measured = to_gtsam_poses(measurements)
    return [between(s, t, pose, noise) for s, t, pose, noise in zip(sources.tolist(), targets.tolist(), measured, noises)]


def robust_mask(graph: PoseGraph, options: SolverOptions) -> np.ndarray:
    """(M,) bool: the edges a kernel applies to."""
    return np.ones(graph.n_edges, dtype=bool) if options.robust_odometry else ~graph.is_odometry()


def build_factor_graph(
    graph: PoseGraph, anchors: Mapping[int, np.ndarray], kernel: str, parameter: float, robust: np.ndarray
) -> tuple[gtsam.NonlinearFactorGraph, FactorLayout]:
    """Between-factors for every edge (in edge order), then priors on ``anchors``."""
    estimator = KERNELS[kernel].build(parameter) if kernel in KERNELS else None
    factor_graph = gtsam.NonlinearFactorGraph()
    for factor in edge_factors(
        graph.dim, graph.sources, graph.targets, graph.measurements, graph.information, robust, estimator
    ):
        factor_graph.add(factor)
    for key, pose in anchors.items():
        factor_graph.add(prior_factor(graph.dim, key, pose))
    return factor_graph, FactorLayout(graph.n_edges, len(anchors))


def objective(graph: PoseGraph, poses: np.ndarray, options: SolverOptions | None = None) -> float:
    """Half the sum of squared whitened residuals of ``graph``'s edges at ``poses``,
    through the kernel of ``options`` (none when None; GNC counts as none)."""
    if options is None or options.kernel == "gnc":
        factor_graph, _ = build_factor_graph(graph, {}, "none", 0.0, np.zeros(graph.n_edges, dtype=bool))
    else:
        factor_graph, _ = build_factor_graph(graph, {}, options.kernel, options.parameter(), robust_mask(graph, options))
    return float(factor_graph.error(to_values(graph.ids, poses)))


# --- optimisation ---------------------------------------------------------------------


def prepare(graph: PoseGraph) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Check the graph can be optimised; return its initial poses and the anchored vertices.

    :raises DataError: disconnected, negative ids (GTSAM keys are unsigned).
    """
    if graph.n_vertices and graph.ids[0] < 0:
        raise DataError(f"{graph.name}: vertex ids must be non-negative, got {int(graph.ids[0])}")
    try:
        check_connected(graph)
        poses = initial_poses(graph)
    except CoreError as exc:
        raise DataError(str(exc)) from None
    anchors = {int(graph.ids[0]): poses[0]}
    for vertex in graph.fixed.tolist():
        anchors[int(vertex)] = poses[int(graph.index_of(np.array([vertex]))[0])]
    return poses, anchors


def _lm_params(options: SolverOptions, iterations: int | None = None) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations or options.max_iterations)
    params.setRelativeErrorTol(options.relative_tolerance)
    params.setAbsoluteErrorTol(options.absolute_tolerance)
    return params


def _solve(graph_name: str, work: Callable[[], Any]) -> Any:
    """Run GTSAM; its exceptions about the problem become one clear DataError."""
    try:
        return work()
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"{graph_name}: GTSAM could not solve the graph: {first}") from None


def optimize(graph: PoseGraph, options: SolverOptions | None = None, g2o_file: Path | None = None) -> OptimizationResult:
    """Optimise ``graph`` as ``options`` say (batch LM, GNC or iSAM2).

    :param g2o_file: a g2o file holding exactly ``graph``, as checked by our reader
        (:attr:`~slamfront.core.graph_files.ParsedGraph.plain_g2o`): batch LM without a
        kernel then has GTSAM's C++ ``readG2o`` build the problem from it (the same
        factors as :func:`build_factor_graph`, in half the time), after checking it read
        the same vertices and edges; anything else builds it from ``graph``.
    :raises DataError: the graph cannot be optimised (disconnected, degenerate).
    """
    options = options or SolverOptions()
    if options.mode == "isam2":
        return _optimize_isam2(graph, options)
    if options.kernel == "gnc":
        return _optimize_gnc(graph, options)
    return _optimize_lm(graph, options, g2o_file if options.kernel == "none" else None)


def _lm(
    name: str, factor_graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, options: SolverOptions
) -> tuple[gtsam.Values, int, bool]:
    """One Levenberg-Marquardt run: the solution, its iteration count, and whether it
    converged (stopped by the tolerances, not by the iteration limit nor by giving up
    at the largest damping, GTSAM's "cannot decrease error with maximum lambda")."""
    params = _lm_params(options)
    optimizer = gtsam.LevenbergMarquardtOptimizer(factor_graph, values, params)
    solution = _solve(name, optimizer.optimize)
    iterations = int(optimizer.iterations())
    gave_up = optimizer.lambda_() >= params.getlambdaUpperBound()
    return solution, iterations, iterations < options.max_iterations and not gave_up


def read_problem(path: Path, graph: PoseGraph, initial: np.ndarray) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values] | None:
    """GTSAM's ``readG2o`` of a file our reader made ``graph`` of: the between-factors of
    every edge in file order and the initial values, or None when GTSAM read something
    else (other counts, other vertices, or other edges among a sample of them)."""
    try:
        factor_graph, values = gtsam.readG2o(str(path), graph.dim == 3)
    except (RuntimeError, ValueError, IndexError):  # GTSAM's exceptions as pybind11 maps them; ours built it
        return None
    if factor_graph.size() != graph.n_edges or values.size() != graph.n_vertices:
        return None
    if not np.array_equal(np.asarray(values.keys(), dtype=np.int64), graph.ids):  # Values iterate in key order
        return None
    if not np.allclose(poses_from_values(values, graph.dim), initial, rtol=0.0, atol=1e-9):
        return None
    information = graph.information if graph.dim == 2 else graph.information[:, _ROTATION_FIRST][:, :, _ROTATION_FIRST]
    for edge in sorted(set(np.linspace(0, graph.n_edges - 1, 16).astype(np.int64).tolist())):  # np.unique imports numpy.ma
        factor = factor_graph.at(edge)
        keys = [int(k) for k in factor.keys()]
        if keys != [int(graph.sources[edge]), int(graph.targets[edge])]:
            return None
        if not np.allclose(factor.measured().matrix(), graph.measurements[edge], rtol=0.0, atol=1e-9):
            return None
        if not np.allclose(factor.noiseModel().information(), information[edge], rtol=1e-9, atol=1e-9):
            return None
    return factor_graph, values


def _optimize_lm(graph: PoseGraph, options: SolverOptions, g2o_file: Path | None = None) -> OptimizationResult:
    initial, anchors = prepare(graph)
    started = time.perf_counter()
    problem = read_problem(g2o_file, graph, initial) if g2o_file is not None else None
    if problem is not None:
        factor_graph, values = problem
        for key, pose in anchors.items():
            factor_graph.add(prior_factor(graph.dim, key, pose))
    else:
        factor_graph, _ = build_factor_graph(graph, anchors, options.kernel, options.parameter(), robust_mask(graph, options))
        values = to_values(graph.ids, initial)
    solution, iterations, converged = _lm(graph.name, factor_graph, values, options)
    return OptimizationResult(
        poses=poses_from_values(solution, graph.dim),
        initial=initial,
        cost_before=float(factor_graph.error(values)),
        cost_after=float(factor_graph.error(solution)),
        iterations=iterations,
        seconds=time.perf_counter() - started,
        converged=converged,
        mode="batch",
        kernel=options.kernel,
    )


def _optimize_gnc(graph: PoseGraph, options: SolverOptions) -> OptimizationResult:
    initial, anchors = prepare(graph)
    started = time.perf_counter()
    plain, layout = build_factor_graph(graph, anchors, "none", 0.0, np.zeros(graph.n_edges, dtype=bool))
    values = to_values(graph.ids, initial)
    start, iterations = values, 0
    if options.gnc_warm_start == "dcs":
        robust, _ = build_factor_graph(graph, anchors, "dcs", KERNELS["dcs"].default_parameter, ~graph.is_odometry())
        start, iterations, _ = _lm(graph.name, robust, values, options)
    params = gtsam.GncLMParams(_lm_params(options, options.gnc_inner_iterations))
    params.setLossType(gtsam.GncLossType.TLS if options.gnc_loss == "tls" else gtsam.GncLossType.GM)
    params.setLambdaStep(options.gnc_step)
    known = [int(i) for i in np.flatnonzero(graph.is_odometry())] + layout.prior_indices
    params.setKnownInliers(known)
    gnc = gtsam.GncLMOptimizer(plain, start, params)
    gnc.setInlierCostThresholdsAtProbability(options.gnc_probability)
    solution = _solve(graph.name, gnc.optimize)
    weights = np.asarray(gnc.getWeights(), dtype=np.float64)
    # A last LM over the weighted graph: GNC's answer is its optimum already, so this
    # only confirms convergence and gives an iteration count GNC itself does not report.
    weighted = _weighted_graph(plain, weights)
    solution, polish_iterations, converged = _lm(graph.name, weighted, solution, options)
    return OptimizationResult(
        poses=poses_from_values(solution, graph.dim),
        initial=initial,
        cost_before=float(plain.error(values)),
        cost_after=float(weighted.error(solution)),
        iterations=iterations + polish_iterations,
        seconds=time.perf_counter() - started,
        converged=converged,
        mode="batch",
        kernel="gnc",
        weights=weights[: graph.n_edges],
    )


def _weighted_graph(plain: gtsam.NonlinearFactorGraph, weights: np.ndarray) -> gtsam.NonlinearFactorGraph:
    """The graph GNC ends with: each factor's error scaled by its weight; zero weights dropped."""
    weighted = gtsam.NonlinearFactorGraph()
    for index in range(plain.size()):
        factor = plain.at(index)
        if weights[index] >= 1.0 - 1e-12:
            weighted.add(factor)
        elif weights[index] > 1e-12:
            information = factor.noiseModel().information() * weights[index]
            weighted.add(factor.cloneWithNewNoiseModel(gtsam.noiseModel.Gaussian.Information(information)))
    return weighted


class Isam2Session:
    """An iSAM2 smoother fed vertex by vertex (the back end's online mode and ``--mode isam2``)."""

    def __init__(self, dim: int, options: SolverOptions, factorization: Literal["cholesky", "qr"] | None = None) -> None:
        self.dim = dim
        self.options = options
        params = gtsam.ISAM2Params()
        # an online session cannot be redone from scratch, so "auto" takes the robust solver
        chosen = factorization or ("qr" if options.isam2_factorization == "auto" else options.isam2_factorization)
        params.setFactorization(chosen.upper())
        self.factorization = chosen
        params.setRelinearizeThreshold(options.isam2_relinearize_threshold)
        params.relinearizeSkip = options.isam2_relinearize_skip
        self.isam = gtsam.ISAM2(params)
        self.kernel = KERNELS[options.kernel].build(options.parameter()) if options.kernel in KERNELS else None
        self.updates = 0
        self.name = "isam2"

    def update(self, factors: list[Any], new_values: Mapping[int, np.ndarray]) -> None:
        """Add factors and the initial guesses of the vertices they introduce, then update."""
        graph = gtsam.NonlinearFactorGraph()
        for factor in factors:
            graph.add(factor)
        values = gtsam.Values()
        for key, pose in new_values.items():
            values.insert(int(key), to_gtsam_pose(pose))
        _solve(self.name, lambda: self.isam.update(graph, values))
        self.updates += 1

    def relinearize(self, times: int) -> None:
        for _ in range(times):
            _solve(self.name, self.isam.update)
            self.updates += 1

    def pose(self, key: int) -> np.ndarray:
        """The current estimate of one vertex."""
        getter = self.isam.calculateEstimatePose2 if self.dim == 2 else self.isam.calculateEstimatePose3
        return np.asarray(getter(int(key)).matrix(), dtype=np.float64)

    def estimate(self) -> np.ndarray:
        """(N, d+1, d+1) current estimate of every vertex, in key order."""
        return poses_from_values(self.isam.calculateEstimate(), self.dim)


def _optimize_isam2(graph: PoseGraph, options: SolverOptions) -> OptimizationResult:
    if options.isam2_factorization != "auto":
        return _isam2_run(graph, options, options.isam2_factorization)
    started = time.perf_counter()
    try:
        return _isam2_run(graph, options, "cholesky")
    except DataError as exc:
        # Cholesky breaks down on ill-conditioned information (e.g. se-sync's intel, CSAIL, MIT);
        # QR is slower but solves them
        if "Indeterminate" not in str(exc):
            raise
    failed_seconds = time.perf_counter() - started
    result = _isam2_run(graph, options, "qr")
    result.seconds += failed_seconds  # the time an "auto" user waits includes the failed attempt
    return result


def _isam2_run(graph: PoseGraph, options: SolverOptions, factorization: Literal["cholesky", "qr"]) -> OptimizationResult:
    initial, anchors = prepare(graph)
    started = time.perf_counter()
    robust = robust_mask(graph, options)
    full, _ = build_factor_graph(graph, anchors, options.kernel, options.parameter(), robust)
    order, parent_edge = spanning_tree(graph)
    step = np.empty(graph.n_vertices, dtype=np.int64)
    step[order] = np.arange(graph.n_vertices)
    src, dst = graph.index_of(graph.sources), graph.index_of(graph.targets)
    by_step: list[list[int]] = [[] for _ in range(graph.n_vertices)]
    for edge, when in enumerate(np.maximum(step[src], step[dst]).tolist()):
        by_step[when].append(edge)
    session = Isam2Session(graph.dim, options, factorization)
    session.name = graph.name
    inverse_measurements = geometry.invert(graph.measurements)
    from tqdm import tqdm  # only the incremental mode shows progress

    progress = tqdm(order.tolist(), desc="iSAM2", unit="vertex", leave=False, disable=None)  # shown on a terminal
    for when, vertex in enumerate(progress):
        key = int(graph.ids[vertex])
        if when == 0:
            guess = initial[vertex]
        else:
            # predict from the parent's current estimate, as an online system would
            edge = parent_edge[vertex]
            parent = src[edge] if dst[edge] == vertex else dst[edge]
            relative = graph.measurements[edge] if dst[edge] == vertex else inverse_measurements[edge]
            guess = session.pose(int(graph.ids[parent])) @ relative
        new_factors = [full.at(e) for e in by_step[when]]
        if key in anchors:
            new_factors.append(prior_factor(graph.dim, key, anchors[key]))
        session.update(new_factors, {key: guess})
    cost = float(full.error(session.isam.calculateEstimate()))
    converged = options.isam2_final_updates == 0
    for _ in range(options.isam2_final_updates):
        session.relinearize(1)
        previous, cost = cost, float(full.error(session.isam.calculateEstimate()))
        converged = previous - cost <= max(options.relative_tolerance * previous, options.absolute_tolerance)
        if converged:
            break
    poses = session.estimate()
    seconds = time.perf_counter() - started
    return OptimizationResult(
        poses=poses,
        initial=initial,
        cost_before=float(full.error(to_values(graph.ids, initial))),
        cost_after=cost,
        iterations=session.updates,
        seconds=seconds,
        converged=converged,
        mode="isam2",
        kernel=options.kernel,
        factorization=factorization,
    )
