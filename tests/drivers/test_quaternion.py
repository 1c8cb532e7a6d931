"""Quaternion conversions: one matrix (Pinocchio's path) and many (scipy's) agree."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.common.quaternion import matrix_to_quat_xyzw, quat_xyzw_to_matrix


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


def test_small_and_large_stacks_and_single_quaternions_agree_with_scipy():
    """The plain-float paths (one quaternion; stacks of up to SMALL_BATCH matrices) give
    scipy's rotations, for quaternions that are not unit too, and every branch of the
    matrix conversion (w, x, y or z the largest component) is taken."""
    from drivers.common.quaternion import SMALL_BATCH

    rng = np.random.default_rng(7)
    q = rng.normal(size=(50, 4)) * rng.uniform(0.2, 5.0, size=(50, 1))
    for qi in q:
        np.testing.assert_allclose(quat_xyzw_to_matrix(qi), Rotation.from_quat(qi).as_matrix(), atol=1e-12)
    # a half turn about each axis and about no axis: each branch's largest component
    R = np.concatenate([Rotation.from_rotvec(np.pi * np.eye(3)).as_matrix(), np.eye(3)[None],
                        Rotation.from_quat(q).as_matrix()])
    assert len(R) <= SMALL_BATCH < 3 * len(R)
    for stack in (R, np.concatenate([R] * 3)):   # the small path and scipy's
        ref = Rotation.from_matrix(stack).as_quat()
        ref[ref[:, 3] < 0] *= -1
        got = matrix_to_quat_xyzw(stack)
        # a half turn has w = 0: q and -q are the same rotation, compare the rotations
        np.testing.assert_allclose(quat_xyzw_to_matrix(got), stack, atol=1e-12)
        np.testing.assert_allclose(got[3:], ref[3:], atol=1e-12)
    bad = R[:5].copy()
    bad[2] = np.nan
    out = matrix_to_quat_xyzw(bad)
    assert np.isnan(out[2]).all() and np.isfinite(np.delete(out, 2, axis=0)).all()
    assert np.isnan(quat_xyzw_to_matrix(np.array([np.nan, 0.0, 0.0, 1.0]))).all()
    with pytest.raises(ValueError, match="zero quaternion"):
        quat_xyzw_to_matrix(np.zeros(4))
