"""Parameters of the ``feature_icp`` registration (Barbosa 2017, section 4.2.2.2).

Radii and the initial-alignment distances are multiples of the voxel size, so one
number (``voxel_size_m``) rescales the whole pipeline to another scene size; the ICP
defaults are the paper's (100 iterations, 0.05 m, epsilon 1e-9).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from slamfront import PluginConfig

Fallback = Literal["wider", "previous_motion"]


class FeatureIcpConfig(PluginConfig):
    """RGB-D -> cloud -> filter -> voxel grid -> normals -> features -> initial alignment -> ICP."""

    # -- RGB-D to cloud ------------------------------------------------------------------
    min_depth_m: float = Field(0.1, ge=0, description="depth at or below this is dropped (no return, sensor blind zone)")
    max_depth_m: float = Field(4.0, gt=0, description="truncation: depth beyond this is dropped (Kinect: about 4 m)")
    pixel_stride: int = Field(1, ge=1, description="use every n-th pixel in both directions (1: all, as the paper)")
    # -- filtering and downsampling ---------------------------------------------------------
    outlier_neighbours: int = Field(
        20, ge=0, description="statistical outlier removal: neighbours per point (0 disables the filter)"
    )
    outlier_std_ratio: float = Field(
        2.0, gt=0, description="drop points whose mean neighbour distance exceeds mean + ratio * std"
    )
    voxel_size_m: float = Field(0.05, gt=0, description="voxel grid for registration (features and ICP)")
    min_points: int = Field(100, ge=4, description="a frame with fewer points after filtering is reported as failed")
    # -- normals and features --------------------------------------------------------------
    normal_radius_voxels: float = Field(2.0, gt=0, description="normal estimation radius, in voxels")
    normal_max_nn: int = Field(30, ge=3, description="at most this many neighbours per normal")
    feature: Literal["fpfh", "pfh", "none"] = Field(
        "fpfh", description="fpfh (33 bins, Open3D), pfh (125 bins, PCL's layout, NumPy) or none (ICP alone)"
    )
    feature_radius_voxels: float = Field(5.0, gt=0, description="feature neighbourhood radius, in voxels")
    feature_max_nn: int = Field(100, ge=2, description="at most this many neighbours per feature")
    # -- initial alignment --------------------------------------------------------------------
    initial_alignment: Literal["ransac", "fgr", "none"] = Field(
        "ransac",
        description="ransac on feature matches (the SAC-IA role), fgr (Fast Global Registration), "
        "or none (ICP from the motion prior)",
    )
    ransac_distance_voxels: float = Field(1.5, gt=0, description="RANSAC inlier distance, in voxels")
    ransac_max_iterations: int = Field(100000, ge=1, description="RANSAC iterations at most")
    ransac_confidence: float = Field(0.999, gt=0, lt=1, description="RANSAC stops early at this confidence")
    ransac_edge_length_ratio: float = Field(
        0.9, gt=0, lt=1, description="reject samples whose edge lengths differ more (similar triangles)"
    )
    mutual_filter: bool = Field(True, description="keep only mutually nearest feature matches")
    fgr_distance_voxels: float = Field(1.5, gt=0, description="FGR correspondence distance, in voxels")
    fgr_iterations: int = Field(64, ge=1, description="FGR iterations")
    seed: int = Field(0, description="random seed of RANSAC (each pair is seeded from it and its frame index)")
    threads: int = Field(
        1, ge=0,
        description="Open3D threads while aligning (0: all cores). 1 makes runs bit-reproducible: Open3D's "
        "parallel RANSAC and ICP reductions otherwise differ in the last bits from run to run",
    )
    # -- ICP ----------------------------------------------------------------------------------
    icp_method: Literal["point_to_point", "point_to_plane"] = Field(
        "point_to_plane",
        description="point_to_plane (converges in fewer iterations and to mm on the samples) or point_to_point "
        "(PCL's IterativeClosestPoint, the paper's; about 1-2 cm off on downsampled clouds)",
    )
    icp_max_iterations: int = Field(100, ge=1, description="ICP iterations at most (paper: 100)")
    icp_distance_m: float = Field(0.05, gt=0, description="ICP maximum correspondence distance (paper: 0.05 m)")
    icp_epsilon: float = Field(
        1e-9, ge=0, description="ICP stops when fitness and inlier RMSE change less than this (paper: 1e-9)"
    )
    motion_prior: Literal["identity", "constant_velocity"] = Field(
        "identity",
        description="ICP's starting guess without features: the previous pose (identity, as the paper) "
        "or the previous motion repeated",
    )
    # -- quality check and fallbacks ----------------------------------------------------------
    min_fitness: float = Field(0.3, ge=0, le=1, description="reject an alignment with a smaller inlier fraction")
    confident_fitness: float = Field(
        0.8, ge=0, le=1,
        description="accept an alignment at once from this fitness; below it the fallbacks are tried too "
        "and the best fit that passes the check is kept (a second opinion on low-overlap pairs)",
    )
    max_inlier_rmse_ratio: float = Field(
        0.6, gt=0, le=1,
        description="reject an alignment whose inlier RMSE exceeds this fraction of icp_distance_m "
        "(residuals spread evenly over the search distance give 0.58)",
    )
    max_translation_m: float | None = Field(
        None, gt=0, description="reject a relative motion longer than this (the robot's speed limit); none: no limit"
    )
    max_rotation_deg: float | None = Field(
        None, gt=0, description="reject a relative rotation larger than this; none: no limit"
    )
    fallbacks: list[Fallback] = Field(
        default_factory=lambda: ["wider", "previous_motion"],
        description="tried in order when an alignment is rejected: wider (larger distances, more iterations) "
        "and previous_motion (ICP from the previous relative motion)",
    )
    wider_factor: float = Field(2.0, gt=1, description="how much wider the 'wider' fallback searches")
    # -- pose graph ---------------------------------------------------------------------------
    pose_graph: bool = Field(False, description="refine the chain with loop edges at the end (Open3D pose graph)")
    loop_radius_m: float = Field(1.0, gt=0, description="try a loop edge between frames whose cameras are this close")
    loop_max_angle_deg: float = Field(45.0, gt=0, le=180, description="... and whose viewing directions differ less")
    loop_min_gap: int = Field(10, ge=2, description="... and that are at least this many frames apart")
    loop_max_per_frame: int = Field(2, ge=1, description="loop registrations tried per frame at most (closest first)")
    loop_preference: float = Field(
        5.0, gt=0, description="pose graph: trust in loop edges against the chain (Open3D's preference_loop_closure)"
    )
    edge_prune_threshold: float = Field(0.25, ge=0, le=1, description="pose graph: loop edges below this weight are dropped")
    # -- output -------------------------------------------------------------------------------
    model_voxel_m: float = Field(0.01, gt=0, description="voxel grid of the global model")
    log_clouds: bool = Field(True, description="log each aligned (downsampled) cloud as foxglove.PointCloud")
    start_pose: Literal["ground_truth", "identity"] = Field(
        "ground_truth",
        description="pose of the first cloud: the source's ground truth when it has one (so estimate and "
        "truth overlay), else identity",
    )

    @model_validator(mode="after")
    def _features_match_alignment(self) -> FeatureIcpConfig:
        if self.initial_alignment != "none" and self.feature == "none":
            raise ValueError(f"initial_alignment {self.initial_alignment!r} needs features: set feature to fpfh or pfh")
        if self.initial_alignment == "none" and self.feature != "none":
            raise ValueError(
                f"feature {self.feature!r} is computed for nothing without an initial alignment: "
                "set initial_alignment to ransac or fgr, or feature to none"
            )
        if self.confident_fitness < self.min_fitness:
            raise ValueError(f"confident_fitness {self.confident_fitness} is below min_fitness {self.min_fitness}")
        if self.min_depth_m >= self.max_depth_m:
            raise ValueError(f"min_depth_m {self.min_depth_m} must be below max_depth_m {self.max_depth_m}")
        return self
