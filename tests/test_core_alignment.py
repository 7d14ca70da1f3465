"""Umeyama alignment and ATE on synthetic point sets (no I/O)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slamfront.core.alignment import ate_rmse, transform_points, umeyama
from slamfront.core.errors import CoreError


def _rotation(d: int, rng: np.random.Generator) -> np.ndarray:
    if d == 2:
        angle = rng.uniform(-np.pi, np.pi)
        return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_recovers_a_known_motion(d: int, with_scale: bool) -> None:
    rng = np.random.default_rng(d)
    src = rng.normal(size=(50, d)) * 10
    rotation, translation = _rotation(d, rng), rng.normal(size=d) * 5
    scale = 2.5 if with_scale else 1.0
    dst = transform_points(src, rotation, translation, scale)
    r, t, s = umeyama(src, dst, with_scale)
    np.testing.assert_allclose(r, rotation, atol=1e-10)
    np.testing.assert_allclose(t, translation, atol=1e-9)
    assert s == pytest.approx(scale, rel=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_umeyama_never_returns_a_reflection() -> None:
    # a mirrored copy is best fitted by a reflection; Umeyama's sign correction refuses it
    src = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [1, 1, 1]], dtype=float)
    dst = src * np.array([-1.0, 1.0, 1.0])
    r, _, _ = umeyama(src, dst)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_ate_is_zero_for_a_moved_copy_and_exact_for_an_offset() -> None:
    rng = np.random.default_rng(1)
    truth = np.cumsum(rng.normal(size=(200, 3)), axis=0)
    moved = transform_points(truth, _rotation(3, rng), np.array([5.0, -2.0, 1.0]))
    assert ate_rmse(moved, truth) < 1e-9
    # without alignment a constant offset of 3-4-0 is an error of 5 everywhere
    assert ate_rmse(truth + np.array([3.0, 4.0, 0.0]), truth, align=False) == pytest.approx(5.0)
    # a random error that alignment cannot remove stays (RMSE of zero-mean noise)
    noise = rng.normal(size=truth.shape) * 0.1
    assert ate_rmse(truth + noise, truth) == pytest.approx(np.sqrt(np.mean(np.sum(noise**2, 1))), rel=0.05)


def test_ate_with_scale_undoes_a_scaled_estimate() -> None:
    truth = np.cumsum(np.random.default_rng(2).normal(size=(100, 2)), axis=0)
    assert ate_rmse(truth * 0.3, truth, with_scale=True) < 1e-9
    assert ate_rmse(truth * 0.3, truth) > 0.1


@pytest.mark.parametrize(
    ("src", "dst", "message"),
    [
        (np.zeros((5, 4)), np.zeros((5, 4)), "(N, 2) or (N, 3)"),
        (np.zeros((5, 3)), np.zeros((4, 3)), "same shape"),
        (np.ones((1, 3)), np.ones((1, 3)), "at least 2"),
        (np.ones((6, 3)), np.zeros((6, 3)), "coincide"),
        (np.full((3, 2), np.nan), np.zeros((3, 2)), "non-finite"),
    ],
)
def test_alignment_refuses_bad_input(src: np.ndarray, dst: np.ndarray, message: str) -> None:
    with pytest.raises(CoreError, match=message.replace("(", r"\(").replace(")", r"\)")):
        umeyama(src, dst)
