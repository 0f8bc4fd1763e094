"""jaxdepth._src.poses (host-side rigid poses) against analytic rotations and NumPy algebra."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxdepth._src import poses


def _axis_angle(axis, angle):
    """Rodrigues' formula: the oracle for every rotation below."""
    k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def test_rotation_rpy_is_yaw_after_pitch_after_roll():
    rng = np.random.default_rng(0)
    for roll, pitch, yaw in rng.uniform(-math.pi, math.pi, (20, 3)):
        want = _axis_angle([0, 0, 1], yaw) @ _axis_angle([0, 1, 0], pitch) @ _axis_angle([1, 0, 0], roll)
        np.testing.assert_allclose(poses.rotation_rpy(roll, pitch, yaw), want, atol=1e-14)
        np.testing.assert_allclose(poses.rotation_rpy(*np.degrees([roll, pitch, yaw]), degrees=True), want,
                                   atol=1e-14)


def test_quaternion_matrix_scalar_first_any_norm_and_errors():
    rng = np.random.default_rng(1)
    for _ in range(20):
        axis, angle, scale = rng.normal(size=3), rng.uniform(-math.pi, math.pi), rng.uniform(0.1, 10.0)
        axis /= np.linalg.norm(axis)
        q = scale * np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])   # (w, x, y, z)
        np.testing.assert_allclose(poses.quaternion_matrix(q), _axis_angle(axis, angle), atol=1e-14)
        np.testing.assert_allclose(poses.quaternion_matrix(-q), _axis_angle(axis, angle), atol=1e-14)
    for bad in ([0, 0, 0, 0], [1, 0, 0], [1, math.nan, 0, 0], "wxyz"):
        with pytest.raises(ValueError, match="field 'cal.rotation' expected"):
            poses.quaternion_matrix(bad, where="cal.rotation")


def test_pose_matrix_invert_and_apply():
    rng = np.random.default_rng(2)
    T = poses.pose_matrix([1.0, -2.0, 0.5], rng.normal(size=4))
    np.testing.assert_allclose(poses.invert_pose(T) @ T, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(poses.invert_pose(T), np.linalg.inv(T), atol=1e-14)
    p = rng.uniform(-50, 50, (100, 3)).astype(np.float32)
    got = poses.apply_pose(T, p)
    assert got.dtype == np.float32
    want = (np.c_[p.astype(np.float64), np.ones(100)] @ T.T)[:, :3]
    np.testing.assert_array_equal(got, want.astype(np.float32))
    with pytest.raises(ValueError, match="field 'ego.translation' expected 3 finite numbers"):
        poses.pose_matrix([1.0, math.inf, 0.0], [1, 0, 0, 0], where="ego")


@pytest.mark.parametrize("angle", [1e-6, 0.02, 1.0, 3.0])
def test_slerp_turns_at_constant_rate_about_the_fixed_axis(angle):
    # small angles included: a normalised linear blend (nlerp) there is off by up to ~1e-10
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    R0 = poses.quaternion_matrix(rng.normal(size=4))
    R1 = R0 @ _axis_angle(axis, angle)
    for a in (0.0, 0.25, 0.5, 0.9, 1.0):
        np.testing.assert_allclose(poses.slerp_rotation(R0, R1, a), R0 @ _axis_angle(axis, a * angle), atol=1e-14)
