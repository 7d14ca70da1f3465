"""Rigid transforms as 4x4 matrices, quaternions in (x, y, z, w) order (as TUM files store them).

A pose ``T_wc`` maps camera coordinates to world coordinates: ``p_w = R p_c + t``.

Planar poses (SE(2)) are 3x3 matrices; :func:`invert`, :func:`relative` and the
batch helpers accept either size and any leading axes. Planar parameters are
``(x, y, theta)`` (theta in radians, counter-clockwise); Euler angles are
``(roll, pitch, yaw)`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (as iSAM files store them);
tangent vectors are ordered translation first, ``(x, y, z, rx, ry, rz)``, as g2o
information matrices are.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slamfront.core.errors import CoreError


def _rotation() -> Any:
    """SciPy's ``Rotation``, imported on first use: ``scipy.spatial`` costs ~0.15 s to import,
    and the quaternion conversions below do without it."""
    from scipy.spatial.transform import Rotation

    return Rotation


def _norm4(q: np.ndarray) -> np.ndarray:
    return np.sqrt(q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1] + q[..., 2] * q[..., 2] + q[..., 3] * q[..., 3])


def quaternion_matrices(quaternions_xyzw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 4) quaternions x, y, z, w (normalised first).

    SciPy's ``Rotation.from_quat(q).as_matrix()`` operation for operation, so the same
    bits (tested), without importing ``scipy.spatial``.
    """
    q = np.asarray(quaternions_xyzw, dtype=np.float64)
    q = q / _norm4(q)[:, None]
    x, y, z, w = q.T
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty((len(q), 3, 3))
    m[:, 0, 0], m[:, 1, 0], m[:, 2, 0] = x2 - y2 - z2 + w2, 2 * (xy + zw), 2 * (xz - yw)
    m[:, 0, 1], m[:, 1, 1], m[:, 2, 1] = 2 * (xy - zw), -x2 + y2 - z2 + w2, 2 * (yz + xw)
    m[:, 0, 2], m[:, 1, 2], m[:, 2, 2] = 2 * (xz + yw), 2 * (yz - xw), -x2 - y2 + z2 + w2
    return m


def matrix_quaternions(matrices: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions x, y, z, w of (N, 3, 3) rotation matrices, by Markley's method as
    SciPy's ``Rotation.from_matrix(m).as_quat()`` computes it (same bits, tested).

    Matrices orthonormal to rounding (``|R R^T - I| <= 1e-13``, what products of rotations
    and optimisers leave) are converted here; SciPy first re-orthogonalises the others,
    so those rows are handed to it.
    """
    m = np.asarray(matrices, dtype=np.float64)
    error = np.abs(m @ np.swapaxes(m, 1, 2) - np.eye(3)).max(axis=(1, 2)) if len(m) else np.zeros(0)
    if np.any(~(error <= 1e-13)):
        q = np.empty((len(m), 4))
        off = ~(error <= 1e-13)
        q[off] = _rotation().from_matrix(m[off]).as_quat()
        q[~off] = matrix_quaternions(m[~off])
        return q
    q = np.empty((len(m), 4))
    diagonal = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    decision = np.column_stack([diagonal, diagonal.sum(axis=1)])
    choice = decision.argmax(axis=1)
    for i in range(3):
        s, j, k = choice == i, (i + 1) % 3, (i + 2) % 3
        q[s, i] = 1 - decision[s, 3] + 2 * m[s, i, i]
        q[s, j] = m[s, j, i] + m[s, i, j]
        q[s, k] = m[s, k, i] + m[s, i, k]
        q[s, 3] = m[s, k, j] - m[s, j, k]
    s = choice == 3
    q[s, 0], q[s, 1], q[s, 2] = m[s, 2, 1] - m[s, 1, 2], m[s, 0, 2] - m[s, 2, 0], m[s, 1, 0] - m[s, 0, 1]
    q[s, 3] = 1 + decision[s, 3]
    return q / _norm4(q)[:, None]


def pose_from_quaternion(translation: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a translation (3,) and a unit quaternion (4,) x, y, z, w.

    The quaternion is normalised first; a zero quaternion is an error.
    """
    q = np.asarray(quaternion_xyzw, dtype=np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise CoreError(f"invalid quaternion {q.tolist()}")
    pose = np.eye(4)
    pose[:3, :3] = quaternion_matrices((q / norm)[None, :])[0]
    pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


def poses_from_quaternions(
    translations: np.ndarray, quaternions_xyzw: np.ndarray, as_single: bool = False
) -> np.ndarray:
    """(N, 4, 4) transforms from (N, 3) translations and (N, 4) quaternions x, y, z, w.

    :param as_single: normalise each quaternion as :func:`pose_from_quaternion` does a lone
        one, so the values are the same bits (a batched norm rounds differently in the
        last bit); a Python loop over the rows, ~1 us each.
    """
    q = np.asarray(quaternions_xyzw, dtype=np.float64)
    if as_single:
        norms = np.array([np.linalg.norm(row) for row in q]).reshape(-1, 1)
    else:
        norms = np.linalg.norm(q, axis=1, keepdims=True)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-12):
        raise CoreError("a quaternion is zero or not finite")
    poses = np.tile(np.eye(4), (len(q), 1, 1))
    poses[:, :3, :3] = quaternion_matrices(q / norms)
    poses[:, :3, 3] = translations
    return poses


def quaternion_of(pose: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion x, y, z, w of a (4, 4) transform's rotation, with w >= 0."""
    q = matrix_quaternions(np.asarray(pose)[None, :3, :3])[0]
    return q if q[3] >= 0 else -q


def dimension_of(transforms: np.ndarray) -> int:
    """2 for (..., 3, 3) arrays, 3 for (..., 4, 4) ones."""
    shape = np.shape(transforms)
    if len(shape) < 2 or shape[-1] != shape[-2] or shape[-1] not in (3, 4):
        raise CoreError(f"expected (..., 3, 3) or (..., 4, 4) transforms, got shape {shape}")
    return shape[-1] - 1


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms, (..., 4, 4) or (..., 3, 3) (R^T, -R^T t: no general inverse)."""
    pose = np.asarray(pose, dtype=np.float64)
    d = dimension_of(pose)
    rotation_t = np.swapaxes(pose[..., :d, :d], -1, -2)
    out = np.zeros_like(pose)
    out[..., :d, :d] = rotation_t
    out[..., :d, d] = -np.einsum("...ij,...j->...i", rotation_t, pose[..., :d, d])
    out[..., d, d] = 1.0
    return out


def relative(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """The transform taking frame b into frame a: ``inv(T_wa) @ T_wb`` (batches broadcast)."""
    return invert(pose_a) @ np.asarray(pose_b, dtype=np.float64)


def rotation_angle_deg(pose: np.ndarray) -> float:
    """Angle of the rotation part in degrees (0 for identity)."""
    cosine = (np.trace(np.asarray(pose)[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def quaternions_of(poses: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions x, y, z, w (w >= 0) of (N, 4, 4) transforms' rotations."""
    q = matrix_quaternions(np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3])
    return q * np.where(q[:, 3:] < 0, -1.0, 1.0)


def se3(translation: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms from (..., 3) translations and (..., 3, 3) rotation matrices."""
    translation = np.asarray(translation, dtype=np.float64)
    out = np.zeros((*translation.shape[:-1], 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def se3_from_euler(translation: np.ndarray, roll_pitch_yaw: np.ndarray) -> np.ndarray:
    """(N, 4, 4) transforms with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (iSAM's convention)."""
    roll_pitch_yaw = np.atleast_2d(np.asarray(roll_pitch_yaw, dtype=np.float64))
    rotation = _rotation().from_euler("ZYX", roll_pitch_yaw[:, ::-1]).as_matrix()
    return se3(np.atleast_2d(translation), rotation)


def exp_se3(tangent: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms ``[Exp(r) t; 0 1]`` from (..., 6) ``(x, y, z, rx, ry, rz)``.

    Translation and rotation are perturbed independently (how odometry noise is drawn
    here), not through the SE(3) exponential's V matrix.
    """
    tangent = np.asarray(tangent, dtype=np.float64)
    rotation = _rotation().from_rotvec(tangent.reshape(-1, 6)[:, 3:]).as_matrix().reshape(*tangent.shape[:-1], 3, 3)
    return se3(tangent[..., :3], rotation)


def se2(x: np.ndarray | float, y: np.ndarray | float, theta: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) planar transforms from ``(x, y, theta)``."""
    x, y, theta = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, y, theta)))
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros((*x.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = c, -s, x
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = s, c, y
    out[..., 2, 2] = 1.0
    return out


def se2_parameters(transforms: np.ndarray) -> np.ndarray:
    """(..., 3) ``(x, y, theta)`` of (..., 3, 3) planar transforms, theta in (-pi, pi]."""
    transforms = np.asarray(transforms, dtype=np.float64)
    theta = np.arctan2(transforms[..., 1, 0], transforms[..., 0, 0])
    return np.stack([transforms[..., 0, 2], transforms[..., 1, 2], theta], axis=-1)


def planar_to_spatial(transforms: np.ndarray) -> np.ndarray:
    """Embed (..., 3, 3) planar transforms in SE(3): z = 0, rotation about z."""
    transforms = np.asarray(transforms, dtype=np.float64)
    out = np.zeros((*transforms.shape[:-2], 4, 4))
    out[..., :2, :2] = transforms[..., :2, :2]
    out[..., :2, 3] = transforms[..., :2, 2]
    out[..., 2, 2] = 1.0
    out[..., 3, 3] = 1.0
    return out
