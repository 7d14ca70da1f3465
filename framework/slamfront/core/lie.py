"""Rigid transforms as homogeneous matrices: SE(2) as (..., 3, 3), SE(3) as (..., 4, 4).

Every function is vectorised over leading axes and returns new arrays. Rotation
parameters follow the file formats slamfront reads: planar poses ``(x, y, theta)``
(theta in radians, counter-clockwise), quaternions ``(qx, qy, qz, qw)`` (scalar last,
as g2o and TUM), Euler angles ``(roll, pitch, yaw)`` with ``R = Rz(yaw) Ry(pitch)
Rx(roll)`` (as iSAM). Tangent vectors are ordered translation first: ``(x, y, theta)``
and ``(x, y, z, rx, ry, rz)``, the order of g2o information matrices.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from slamfront.core.errors import CoreError


def dimension_of(transforms: np.ndarray) -> int:
    """2 for (..., 3, 3) arrays, 3 for (..., 4, 4) ones."""
    shape = np.shape(transforms)
    if len(shape) < 2 or shape[-1] != shape[-2] or shape[-1] not in (3, 4):
        raise CoreError(f"expected (..., 3, 3) or (..., 4, 4) transforms, got shape {shape}")
    return shape[-1] - 1


def inverse(transforms: np.ndarray) -> np.ndarray:
    """Inverse rigid transforms, exactly (R^T, -R^T t), no general matrix inversion."""
    transforms = np.asarray(transforms, dtype=np.float64)
    d = dimension_of(transforms)
    rotation_t = np.swapaxes(transforms[..., :d, :d], -1, -2)
    result = np.zeros_like(transforms)
    result[..., :d, :d] = rotation_t
    result[..., :d, d] = -np.einsum("...ij,...j->...i", rotation_t, transforms[..., :d, d])
    result[..., d, d] = 1.0
    return result


def relative(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """``first^-1 @ second``: the pose of ``second`` seen from ``first``."""
    return inverse(first) @ np.asarray(second, dtype=np.float64)


def se2(x: np.ndarray | float, y: np.ndarray | float, theta: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) transforms from planar poses."""
    x, y, theta = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, y, theta)))
    c, s = np.cos(theta), np.sin(theta)
    result = np.zeros((*x.shape, 3, 3))
    result[..., 0, 0], result[..., 0, 1], result[..., 0, 2] = c, -s, x
    result[..., 1, 0], result[..., 1, 1], result[..., 1, 2] = s, c, y
    result[..., 2, 2] = 1.0
    return result


def se2_parameters(transforms: np.ndarray) -> np.ndarray:
    """(..., 3) ``(x, y, theta)`` of (..., 3, 3) transforms, theta in (-pi, pi]."""
    transforms = np.asarray(transforms, dtype=np.float64)
    theta = np.arctan2(transforms[..., 1, 0], transforms[..., 0, 0])
    return np.stack([transforms[..., 0, 2], transforms[..., 1, 2], theta], axis=-1)


def se3(translation: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms from (..., 3) translations and (..., 3, 3) rotation matrices."""
    translation = np.asarray(translation, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64)
    result = np.zeros((*translation.shape[:-1], 4, 4))
    result[..., :3, :3] = rotation
    result[..., :3, 3] = translation
    result[..., 3, 3] = 1.0
    return result


def se3_from_quaternion(translation: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """(N, 4, 4) transforms from (N, 3) translations and (N, 4) quaternions (normalised here).

    :raises CoreError: a quaternion has zero norm.
    """
    quaternion_xyzw = np.atleast_2d(np.asarray(quaternion_xyzw, dtype=np.float64))
    norms = np.linalg.norm(quaternion_xyzw, axis=-1)
    if np.any(norms < 1e-12) or not np.all(np.isfinite(norms)):
        raise CoreError("a quaternion has zero or non-finite norm")
    rotation = Rotation.from_quat(quaternion_xyzw / norms[:, None]).as_matrix()
    return se3(np.atleast_2d(translation), rotation)


def se3_to_quaternion(transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(translations (N, 3), quaternions (N, 4) xyzw with qw >= 0)`` of (N, 4, 4) transforms."""
    transforms = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
    quaternion = Rotation.from_matrix(transforms[:, :3, :3]).as_quat()
    quaternion *= np.where(quaternion[:, 3:] < 0, -1.0, 1.0)
    return transforms[:, :3, 3].copy(), quaternion


def se3_from_euler(translation: np.ndarray, roll_pitch_yaw: np.ndarray) -> np.ndarray:
    """(N, 4, 4) transforms with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (iSAM's convention)."""
    roll_pitch_yaw = np.atleast_2d(np.asarray(roll_pitch_yaw, dtype=np.float64))
    rotation = Rotation.from_euler("ZYX", roll_pitch_yaw[:, ::-1]).as_matrix()
    return se3(np.atleast_2d(translation), rotation)


def planar_to_spatial(transforms: np.ndarray) -> np.ndarray:
    """Embed (..., 3, 3) SE(2) transforms in SE(3) (z = 0, rotation about z)."""
    transforms = np.asarray(transforms, dtype=np.float64)
    result = np.zeros((*transforms.shape[:-2], 4, 4))
    result[..., :2, :2] = transforms[..., :2, :2]
    result[..., :2, 3] = transforms[..., :2, 2]
    result[..., 2, 2] = 1.0
    result[..., 3, 3] = 1.0
    return result


def exp_se3(tangent: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms ``T = [Exp(r) t; 0 1]`` from (..., 6) ``(x, y, z, rx, ry, rz)``.

    Translation and rotation are perturbed independently (the convention of the noise
    models used for odometry here), not through the SE(3) exponential's V matrix.
    """
    tangent = np.asarray(tangent, dtype=np.float64)
    rotation = Rotation.from_rotvec(tangent.reshape(-1, 6)[:, 3:]).as_matrix().reshape(*tangent.shape[:-1], 3, 3)
    return se3(tangent[..., :3], rotation)


def rotation_angle(transforms: np.ndarray) -> np.ndarray:
    """(...) rotation angle in radians of each transform (geodesic distance to identity)."""
    transforms = np.asarray(transforms, dtype=np.float64)
    d = dimension_of(transforms)
    if d == 2:
        return np.abs(np.arctan2(transforms[..., 1, 0], transforms[..., 0, 0]))
    trace = np.trace(transforms[..., :3, :3], axis1=-2, axis2=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
