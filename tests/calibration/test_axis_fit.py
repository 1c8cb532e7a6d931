"""Axis-of-rotation fits (appendix A.1) against known truth, with 0.25 mm marker noise."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.axis_fit import (axis_angle, axis_distance, common_perpendicular, distance_in_plane,
                                  fit_axis, fit_axis_bias_compensated, fit_axis_gamage_lasenby)
from calibration.fit_error import FitError
from calibration.registration import to_static_reference
from calibration.synthetic import hinge_scene


def perpendicular_error(fit, scene):
    d = fit.point - scene.point
    return np.linalg.norm(d - (d @ scene.direction) * scene.direction)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("half_range", [1.5, 0.9])  # PSM q1 and q2 sweeps (rad)
def test_axis_direction_and_point_within_targets(seed, half_range):
    hs = hinge_scene(np.random.default_rng(seed), angle_range=(-half_range, half_range), n_frames=300)
    X, _ = to_static_reference(hs.moving_markers, hs.ref_markers, hs.ref_template)
    for fit in (fit_axis_gamage_lasenby(X), fit_axis_bias_compensated(X)):
        assert np.rad2deg(axis_angle(fit.direction, hs.direction)) < 0.1
        assert perpendicular_error(fit, hs) < 0.2e-3
        assert fit.range == pytest.approx(2 * half_range, abs=0.015)
        # the reported uncertainty and residual are in the right range, not zero
        assert 0.003 < np.rad2deg(fit.direction_std) < 0.1
        assert 0.2e-3 < fit.residual_rms < 0.5e-3
        assert fit.noise_sigma == pytest.approx(0.25e-3, rel=0.2)


def test_axis_with_reference_tracked_every_frame():
    """A moving reference body adds its rotation noise times the lever arm."""
    hs = hinge_scene(np.random.default_rng(7), n_frames=300)
    fit = fit_axis(hs.markers_in_reference())
    err = axis_angle(fit.direction, hs.direction)
    assert np.rad2deg(err) < 0.2
    assert err < 4 * fit.direction_std  # the uncertainty covers the error


def test_plain_gamage_lasenby_is_biased_at_small_range_compensated_less():
    """+/-0.1 rad (11.5 deg) sweeps: the plain centre is pulled toward the markers."""
    bias_gl, bias_bc, err_gl, err_bc = [], [], [], []
    for seed in range(30):
        hs = hinge_scene(np.random.default_rng(100 + seed), angle_range=(-0.1, 0.1), n_frames=300)
        X, _ = to_static_reference(hs.moving_markers, hs.ref_markers, hs.ref_template)
        # unit in-plane direction from the true axis toward the markers
        c = np.nanmean(X.reshape(-1, 3), axis=0) - hs.point
        c -= (c @ hs.direction) * hs.direction
        c /= np.linalg.norm(c)
        for fit, bias, err in ((fit_axis_gamage_lasenby(X), bias_gl, err_gl),
                               (fit_axis_bias_compensated(X), bias_bc, err_bc)):
            bias.append((fit.point - hs.point) @ c)
            err.append(perpendicular_error(fit, hs))
    assert np.mean(bias_gl) > 0.8e-3  # systematic: radius underestimated by ~1 mm
    assert abs(np.mean(bias_bc)) < 0.25 * np.mean(bias_gl)
    assert np.median(err_bc) < 0.5 * np.median(err_gl)


def test_too_little_range_of_motion_is_refused():
    hs = hinge_scene(np.random.default_rng(1), angle_range=(-0.03, 0.03), n_frames=300)
    X, _ = to_static_reference(hs.moving_markers, hs.ref_markers, hs.ref_template)
    with pytest.raises(FitError, match=r"too little range of motion: [34]\.\d+ deg swept about the axis "
                                       r"\(need at least 10\.0 deg\)") as e:
        fit_axis_bias_compensated(X)
    assert e.value.condition["range_deg"] == pytest.approx(3.44, abs=1.0)


def test_too_few_frames_is_refused():
    hs = hinge_scene(np.random.default_rng(2), n_frames=12)
    with pytest.raises(FitError, match=r"too few frames: 12 \(need at least 20\)"):
        fit_axis_gamage_lasenby(hs.markers_in_reference())


def test_occluded_markers_are_skipped_then_refused_when_too_many():
    hs = hinge_scene(np.random.default_rng(3), n_frames=300)
    X = hs.markers_in_reference(exact_reference=True)
    rng = np.random.default_rng(0)
    some = X.copy()
    some[rng.random(some.shape[:2]) < 0.3] = np.nan  # 30 % of marker samples lost
    fit = fit_axis_bias_compensated(some)
    assert np.rad2deg(axis_angle(fit.direction, hs.direction)) < 0.1
    assert fit.occluded_fraction == pytest.approx(0.3, abs=0.05)
    many = X.copy()
    many[rng.random(many.shape[:2]) < 0.7] = np.nan
    with pytest.raises(FitError, match=r"too many occluded frames: 7\d% of marker samples missing "
                                       r"\(limit 50%; marker 0: \d+%"):
        fit_axis_bias_compensated(many)


def test_no_rotation_is_refused_by_eigenvalue_ratio():
    hs = hinge_scene(np.random.default_rng(4), angle_range=(0.0, 0.0), n_frames=100)
    with pytest.raises(FitError, match="do not move in planes about one axis"):
        fit_axis_gamage_lasenby(hs.markers_in_reference(exact_reference=True), min_range=0.0)


def test_line_distance_helpers_on_known_geometry():
    d, f1, f2 = common_perpendicular([0, 0, 0], [1, 0, 0], [0, 1, 5], [0, 0, 1])
    assert d == pytest.approx(1.0)
    np.testing.assert_allclose(f1, [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(f2, [0, 1, 0], atol=1e-12)
    # parallel axes 0.15 m apart: both measures agree, whatever the axes' sign
    assert common_perpendicular([0, 0, 0], [0, 0, 1], [0.15, 0, 3], [0, 0, -1])[0] == pytest.approx(0.15)
    assert distance_in_plane([0, 0, 0], [0, 0, 1], [0.15, 0, 3], [0, 0, -1]) == pytest.approx(0.15)
    # slightly skew: the in-plane distance depends on where the plane is put
    tilt = np.array([np.sin(0.01), 0, np.cos(0.01)])
    d0 = distance_in_plane([0, 0, 0], [0, 0, 1], [0.15, 0, 0], tilt, at=[0, 0, 0])
    d1 = distance_in_plane([0, 0, 0], [0, 0, 1], [0.15, 0, 0], tilt, at=[0, 0, 0.1])
    assert d0 == pytest.approx(0.15, rel=1e-4)
    assert d1 - d0 == pytest.approx(0.1 * 0.01, rel=0.01)  # the axes diverge by 0.01 rad
    assert np.rad2deg(axis_angle([0, 0, 1], -tilt)) == pytest.approx(np.rad2deg(0.01))


def test_fitted_parallel_axes_distance_within_0_3_mm():
    """Two hinges 0.150 m apart on a common reference (a Table 4.1 link length)."""
    rng = np.random.default_rng(11)
    base = hinge_scene(rng, n_frames=300)
    fits = []
    for offset in (0.0, 0.150):
        e = np.cross(base.direction, [1.0, 0.0, 0.0])
        e /= np.linalg.norm(e)
        hs = hinge_scene(np.random.default_rng(12 + int(offset * 1e3)), n_frames=300,
                         direction=base.direction, point=base.point + offset * e)
        fits.append((fit_axis_bias_compensated(hs.markers_in_reference(exact_reference=True)), hs))
    (f1, h1), (f2, h2) = fits
    d, sd = axis_distance(f1, f2, kind="plane")
    assert d == pytest.approx(0.150, abs=0.3e-3)
    assert 0 < sd < 0.3e-3
    assert abs(d - 0.150) < 4 * sd + 1e-5
