"""Quaternion conversions: one matrix (Pinocchio's path) and many (scipy's) agree."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.quaternion import matrix_to_quat_xyzw, quat_xyzw_to_matrix


def test_one_matrix_gives_the_same_quaternion_as_a_batch():
    rotations = Rotation.random(200, random_state=3).as_matrix()
    batch = matrix_to_quat_xyzw(rotations)
    assert np.all(batch[:, 3] >= 0)
    for R, q in zip(rotations, batch):
        one = matrix_to_quat_xyzw(R)
        assert one.shape == (4,) and one[3] >= 0
        np.testing.assert_allclose(one, q, atol=1e-12)
        np.testing.assert_allclose(quat_xyzw_to_matrix(one), R, atol=1e-12)


def test_a_half_turn_and_a_nan_matrix():
    # w = 0: the sign is the rotation's either way; the matrix comes back
    R = Rotation.from_rotvec([0.0, np.pi, 0.0]).as_matrix()
    np.testing.assert_allclose(quat_xyzw_to_matrix(matrix_to_quat_xyzw(R)), R, atol=1e-12)
    assert np.isnan(matrix_to_quat_xyzw(np.full((3, 3), np.nan))).all()
