"""Rigid registration and base-to-base transforms against known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.fit_error import FitError
from calibration.registration import (invert, kabsch, pose_error, register_from_mocap,
                                      register_from_touch_points, rigid_body_poses, rotation_angle)
from calibration.synthetic import registration_scene


def test_kabsch_exact_and_proper_rotation():
    rng = np.random.default_rng(0)
    R = Rotation.random(random_state=1).as_matrix()
    t = np.array([0.1, -0.2, 0.3])
    a = rng.uniform(-0.1, 0.1, (10, 3))
    fit = kabsch(a, a @ R.T + t)
    np.testing.assert_allclose(fit.rotation, R, atol=1e-12)
    np.testing.assert_allclose(fit.translation, t, atol=1e-12)
    assert fit.residual_rms < 1e-12
    # nearly planar noisy points, the case where plain SVD can return a reflection
    a[:, 2] = 0.0
    b = a @ R.T + t + rng.normal(scale=1e-4, size=a.shape)
    fit = kabsch(a, b)
    assert np.linalg.det(fit.rotation) == pytest.approx(1.0)
    assert np.rad2deg(rotation_angle(fit.rotation.T @ R)) < 0.2


@pytest.mark.parametrize("seed", range(5))
def test_touch_point_registration_within_targets(seed):
    rs = registration_scene(np.random.default_rng(seed), n_points=40, workspace=0.1)
    fit = register_from_touch_points(rs.tips_1, rs.tips_2)
    dt, dr = pose_error(fit.matrix(), rs.T_1_2)
    assert dt < 0.5e-3 and np.rad2deg(dr) < 0.2
    # both tips noisy: 3-D residual RMS ~ sqrt(2 x 3 x (1 - 6/120)) x 0.25 mm = 0.60 mm
    assert 0.45e-3 < fit.residual_rms < 0.75e-3
    assert dr < 4 * fit.rotation_std


@pytest.mark.parametrize("seed", range(5))
def test_mocap_registration_within_targets(seed):
    rs = registration_scene(np.random.default_rng(seed))
    fit = register_from_mocap(rs.T_m_b1, rs.T_m_b2)
    dt, dr = pose_error(fit.matrix(), rs.T_1_2)
    assert dt < 0.5e-3 and np.rad2deg(dr) < 0.2
    assert fit.condition == {"samples_1": 200, "samples_2": 200}


def test_mocap_registration_composes_body_offsets_and_skips_occluded():
    rs = registration_scene(np.random.default_rng(9))
    off1 = np.eye(4)
    off1[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    off1[:3, 3] = [0.01, 0.02, -0.05]
    off2 = np.eye(4)
    off2[:3, 3] = [0.0, 0.0, 0.1]
    # the bodies sit at base * inv(offset): composing the offsets must give the bases back
    T1 = rs.T_m_b1 @ invert(off1)
    T2 = rs.T_m_b2 @ invert(off2)
    T1[::4] = np.nan  # occluded samples
    fit = register_from_mocap(T1, T2, off1, off2)
    dt, dr = pose_error(fit.matrix(), rs.T_1_2)
    assert dt < 0.5e-3 and np.rad2deg(dr) < 0.2
    assert fit.condition["samples_1"] == 150


def test_degenerate_point_sets_are_refused():
    line = np.outer(np.linspace(0, 0.1, 10), [1.0, 0.0, 0.0])
    with pytest.raises(FitError, match="nearly collinear"):
        register_from_touch_points(line, line + 0.01)
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (3, 3))
    with pytest.raises(FitError, match=r"3 usable point pairs, need at least 4"):
        register_from_touch_points(pts, pts)
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (6, 3))
    pts2 = pts.copy()
    pts2[:3] = np.nan
    with pytest.raises(FitError, match=r"3 usable point pairs"):
        register_from_touch_points(pts, pts2)


def test_rigid_body_poses_handle_partial_occlusion():
    rng = np.random.default_rng(2)
    tpl = rng.uniform(-0.04, 0.04, (4, 3))
    tpl -= tpl.mean(axis=0)
    R = Rotation.random(20, random_state=3).as_matrix()
    p = rng.uniform(-1, 1, (20, 3))
    X = np.einsum("kij,pj->kpi", R, tpl) + p[:, None]
    X[5, 1] = np.nan  # 3 of 4 markers: still solvable
    X[6, :2] = np.nan  # 2 of 4: not
    Re, pe, valid = rigid_body_poses(X, tpl)
    assert valid.tolist() == [k != 6 for k in range(20)]
    np.testing.assert_allclose(Re[valid], R[valid], atol=1e-10)
    np.testing.assert_allclose(pe[valid], p[valid], atol=1e-10)
    assert np.all(np.isnan(pe[6]))
