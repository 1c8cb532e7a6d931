"""Pivot calibration (appendix A.2, Table 6.1) against a known RCM, 0.25 mm marker noise."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.fit_error import FitError
from calibration.pivot import fit_pivot, pivot_one_step, pivot_ransac
from calibration.synthetic import pivot_scene


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("method", ["one_step", "two_step"])
def test_rcm_within_0_2_mm_over_psm_sweeps(seed, method):
    ps = pivot_scene(np.random.default_rng(seed), n_frames=400, q1_range=1.5, q2_range=0.9)
    fit = fit_pivot(ps.R, ps.p, method=method)
    assert np.linalg.norm(fit.post - ps.rcm) < 0.2e-3
    assert np.linalg.norm(fit.tip - ps.tip) < 0.3e-3
    # Table 6.1 form: per-axis RMS of the per-frame RCM estimates, sub-millimetre here
    assert fit.rms_xyz.shape == (3,) and np.all((0.1e-3 < fit.rms_xyz) & (fit.rms_xyz < 1.0e-3))
    assert fit.rms == pytest.approx(np.sqrt(np.mean(np.sum((fit.points - fit.post) ** 2, axis=1))))
    assert np.all(fit.post_std > 0) and np.all(np.abs(fit.post - ps.rcm) < 5 * fit.post_std + 1e-5)


def test_sphere_variant_agrees():
    ps = pivot_scene(np.random.default_rng(21), n_frames=400)
    fit = fit_pivot(ps.R, ps.p, method="sphere")
    assert np.linalg.norm(fit.post - ps.rcm) < 0.3e-3
    assert fit.condition["sphere_radius"] == pytest.approx(0.15, abs=1e-3)


def test_summary_has_the_json_fields_in_metres():
    ps = pivot_scene(np.random.default_rng(1), n_frames=200)
    s = fit_pivot(ps.R, ps.p).summary()
    assert set(s) >= {"rcm", "tip_offset", "rms"}
    np.testing.assert_allclose(s["rcm"], ps.rcm, atol=0.3e-3)


def test_ransac_rejects_outlier_frames():
    rng = np.random.default_rng(5)
    ps = pivot_scene(rng, n_frames=400)
    p = ps.p.copy()
    bad = rng.random(len(p)) < 0.15  # marker swaps: the body jumps 5-20 mm
    jump = rng.normal(size=(bad.sum(), 3))
    p[bad] += jump / np.linalg.norm(jump, axis=1)[:, None] * rng.uniform(5e-3, 20e-3, (bad.sum(), 1))
    plain = pivot_one_step(ps.R, p)
    robust = pivot_ransac(ps.R, p, seed=0)
    assert np.linalg.norm(plain.post - ps.rcm) > 0.5e-3
    assert np.linalg.norm(robust.post - ps.rcm) < 0.3e-3
    assert np.all(~robust.inliers[bad])  # every corrupted frame rejected
    assert robust.inliers[~bad].mean() > 0.97
    # as good as a fit told which frames were clean
    clean = pivot_one_step(ps.R, p, _used=~bad)
    assert np.linalg.norm(robust.post - clean.post) < 0.02e-3
    assert robust.condition["outliers"] == (~robust.inliers).sum()
    again = pivot_ransac(ps.R, p, seed=0)
    np.testing.assert_array_equal(again.post, robust.post)  # seeded: reproducible


def test_single_axis_sweep_is_refused():
    q1 = np.linspace(-1.5, 1.5, 300)
    ps = pivot_scene(np.random.default_rng(2), q1=q1, q2=np.zeros_like(q1))
    with pytest.raises(FitError, match=r"nearly singular .* rotations are about one axis only.*sweep "
                                       r"both q1 and q2"):
        pivot_one_step(ps.R, ps.p)


def test_too_little_rotation_is_refused():
    ps = pivot_scene(np.random.default_rng(3), n_frames=300, q1_range=0.04, q2_range=0.04)
    with pytest.raises(FitError, match=r"too little rotation: \d\.\d+ deg between the most different "
                                       r"poses \(need at least 10\.0 deg\)") as e:
        pivot_one_step(ps.R, ps.p)
    assert np.rad2deg(e.value.condition["rotation_range"]) < 10


def test_too_few_frames_and_occlusions_are_refused():
    ps = pivot_scene(np.random.default_rng(4), n_frames=15)
    with pytest.raises(FitError, match=r"too few frames: 15 usable of 15 \(need at least 20"):
        pivot_one_step(ps.R, ps.p)
    ps = pivot_scene(np.random.default_rng(4), n_frames=300)
    R, p = ps.R.copy(), ps.p.copy()
    R[10:], p[10:] = np.nan, np.nan  # body lost after 10 frames
    with pytest.raises(FitError, match=r"too few frames: 10 usable of 300 .*occluded frames are not usable"):
        pivot_one_step(R, p)
    R, p = ps.R.copy(), ps.p.copy()
    R[::3], p[::3] = np.nan, np.nan  # a third occluded: still fine, and counted
    fit = pivot_one_step(R, p)
    assert fit.condition["frames_rejected"] == 100 and np.all(np.isnan(fit.points[::3]))
    assert np.linalg.norm(fit.post - ps.rcm) < 0.3e-3
