"""Rigid transforms as 4x4 matrices, quaternions in (x, y, z, w) order (as TUM files store them).

A pose ``T_wc`` maps camera coordinates to world coordinates: ``p_w = R p_c + t``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from slamfront.core.errors import CoreError


def pose_from_quaternion(translation: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a translation (3,) and a unit quaternion (4,) x, y, z, w.

    The quaternion is normalised first; a zero quaternion is an error.
    """
    q = np.asarray(quaternion_xyzw, dtype=np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise CoreError(f"invalid quaternion {q.tolist()}")
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(q / norm).as_matrix()
    pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


def poses_from_quaternions(translations: np.ndarray, quaternions_xyzw: np.ndarray) -> np.ndarray:
    """(N, 4, 4) transforms from (N, 3) translations and (N, 4) quaternions x, y, z, w."""
    q = np.asarray(quaternions_xyzw, dtype=np.float64)
    norms = np.linalg.norm(q, axis=1, keepdims=True)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-12):
        raise CoreError("a quaternion is zero or not finite")
    poses = np.tile(np.eye(4), (len(q), 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(q / norms).as_matrix()
    poses[:, :3, 3] = translations
    return poses


def quaternion_of(pose: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion x, y, z, w of a (4, 4) transform's rotation, with w >= 0."""
    q = Rotation.from_matrix(np.asarray(pose)[:3, :3]).as_quat()
    return q if q[3] >= 0 else -q


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform (uses R^T rather than a general inverse)."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    out = np.eye(4)
    out[:3, :3] = rotation.T
    out[:3, 3] = -rotation.T @ translation
    return out


def relative(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """The transform taking frame b into frame a: ``inv(T_wa) @ T_wb``."""
    return invert(pose_a) @ pose_b


def rotation_angle_deg(pose: np.ndarray) -> float:
    """Angle of the rotation part in degrees (0 for identity)."""
    cosine = (np.trace(np.asarray(pose)[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
