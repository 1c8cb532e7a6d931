"""OLS, WLS and SDP against known truth; physical checks; non-exciting data."""

import numpy as np
import pytest

from calibration.base_params import RankDeficientError, base_parameters_of
from calibration.estimators import (Identification, check_physical, normalised_condition,
                                    validation_errors)
from calibration.layout import pseudo_inertia
from calibration.reference_arm import ReferenceArm


def identification(arm, base, q, dq, ddq, W, tau, **kw):
    return Identification(base.regressor(W), tau, base, arm.param_layout, nominal=arm.nominal_params(),
                          regressor=arm.regressor, q_check=q[::100], **kw)


@pytest.mark.parametrize("method", ["ols", "wls", "sdp"])
def test_noiseless_recovery(arm, base, trajectory, method, make_trajectory):
    t, q, dq, ddq, W = trajectory
    tau = (W @ arm.true_params()).reshape(-1, 3)
    fit = getattr(identification(arm, base, q, dq, ddq, W, tau), method)()
    pred = fit.predict(base.regressor(W), 3)
    rel = np.linalg.norm(pred - tau, axis=0) / np.linalg.norm(tau, axis=0)
    assert np.all(rel < 1e-6), rel
    # The base parameters themselves are recovered (they are identifiable).
    beta_true = base.K @ arm.true_params()
    assert np.linalg.norm(fit.beta - beta_true) < 1e-4 * np.linalg.norm(beta_true)
    assert fit.checks["all_pass"], fit.checks
    # On fresh samples of another trajectory, too: the model generalises.
    _, q2, dq2, ddq2 = make_trajectory(arm, seed=5, duration=10.0, rate=50.0)
    W2 = arm.regressor_batch(q2, dq2, ddq2)
    tau2 = (W2 @ arm.true_params()).reshape(-1, 3)
    err = validation_errors(tau2, fit.predict(base.regressor(W2), 3))
    assert np.all(err["relative_error"] < 1e-6)


def test_noisy_recovery_within_expected_error(arm, base, trajectory):
    """With white noise sigma, the LS prediction error on the fitted samples is the noise's
    projection on the r-dimensional column space: about sigma * sqrt(r)."""
    t, q, dq, ddq, W = trajectory
    tau = (W @ arm.true_params()).reshape(-1, 3)
    sigma = 0.02
    noisy = tau + sigma * np.random.default_rng(4).normal(size=tau.shape)
    ident = identification(arm, base, q, dq, ddq, W, noisy)
    expected = sigma * np.sqrt(base.n_base)
    Wb = base.regressor(W)
    for fit in (ident.ols(), ident.wls(), ident.sdp()):
        err = np.linalg.norm(Wb @ fit.beta - tau.ravel())
        assert 0.3 * expected < err < 3.0 * expected, (fit.method, err, expected)
        # The residual to the measurement is the noise itself.
        assert fit.residual_norm == pytest.approx(sigma * np.sqrt(tau.size), rel=0.05)
    # Equal noise on every joint: residual-std weights are nearly equal.
    a = ident.wls().weights
    assert a.max() / a.min() < 1.1
    assert ident.wls().weights == pytest.approx(1 / (ident.ols().residual_norm / np.sqrt(tau.size)), rel=0.1)


def test_sdp_feasible_where_ols_is_not(make_trajectory):
    """Few samples, large noise and bodies on the boundary of physical consistency (point
    masses): OLS gives torques no physical arm produces; the SDP does not."""
    arm = ReferenceArm(seed=0, point_mass_bodies=("link3", "tool", "counterweight2"))
    base = base_parameters_of(arm.regressor_batch, arm.param_layout, arm.q_min, arm.q_max, arm.dq_max)
    t, q, dq, ddq = make_trajectory(arm, seed=3, duration=2.0, rate=200.0)
    W = arm.regressor_batch(q, dq, ddq)
    tau = (W @ arm.true_params()).reshape(-1, 3)
    tau = tau + 0.05 * np.abs(tau).max(0) * np.random.default_rng(3).normal(size=tau.shape)
    ident = identification(arm, base, q, dq, ddq, W, tau)
    ols, sdp = ident.ols(), ident.sdp()
    assert not ols.checks["realizable"]["pass"]
    assert not ols.checks["all_pass"]
    assert sdp.checks["all_pass"]
    for name, eig in sdp.checks["pseudo_inertia_psd"]["eigenvalues"].items():
        assert min(eig) > -1e-7, name
    assert all(m > 0 for m in sdp.checks["masses_positive"]["masses"].values())
    assert sdp.checks["mass_matrix_pd"]["min_eigenvalue"] > 0
    # ... and the SDP fit is the best physical one: its residual is within the gap of OLS's.
    assert sdp.residual_norm >= ols.residual_norm - 1e-9


def test_sdp_bounds_and_pull_toward_nominal(arm, base, trajectory):
    t, q, dq, ddq, W = trajectory
    tau = (W @ arm.true_params()).reshape(-1, 3)
    ident = identification(arm, base, q, dq, ddq, W, tau)
    fit = ident.sdp()
    # The unidentifiable part of the solution is pulled to the nominal one: the true
    # parameters give the same torques and are feasible, so the solution must be at least
    # as close to nominal in the null space, and here it is far closer.
    N, pi0 = base.null_basis, arm.nominal_params()
    d_fit = np.linalg.norm(N.T @ (fit.pi - pi0))
    d_true = np.linalg.norm(N.T @ (arm.true_params() - pi0))
    assert d_fit < 0.01 * d_true
    # A per-body mass box is honoured.
    m_true = arm.true_params()[arm.param_layout.mass_index(6)]
    boxed = ident.sdp(mass_bounds={"counterweight1": (m_true + 0.5, None)})
    assert boxed.pi[arm.param_layout.mass_index(6)] >= m_true + 0.5 - 1e-6
    assert boxed.checks["all_pass"]
    total = ident.sdp(total_mass=(None, 3.0))
    assert total.pi[arm.param_layout.mass_indices].sum() <= 3.0 + 1e-6
    with pytest.raises(RuntimeError, match="bounds"):
        ident.sdp(total_mass=(5.0, 1.0))


def test_wls_weightings_and_table_figures(arm, base, trajectory):
    t, q, dq, ddq, W = trajectory
    tau = (W @ arm.true_params()).reshape(-1, 3)
    rng = np.random.default_rng(8)
    tau = tau + np.array([0.01, 0.01, 0.2]) * rng.normal(size=tau.shape)  # joint 3 noisier
    ident = identification(arm, base, q, dq, ddq, W, tau)
    default = ident.wls()
    assert default.info["weighting"] == "residual_std"
    assert default.weights[2] < default.weights[0] / 5  # the noisy joint is trusted less
    tm = ident.wls("tau_max")
    np.testing.assert_allclose(tm.weights, 1 / np.abs(tau).max(0))
    Wb = base.regressor(W)
    assert ident.ols().condition == pytest.approx(normalised_condition(Wb))
    assert tm.condition == pytest.approx(normalised_condition(Wb * np.tile(tm.weights, len(q))[:, None]))
    # Weighting by the noise beats ignoring it on the noisy joint's neighbours.
    truth = (W @ arm.true_params())
    assert np.linalg.norm(Wb @ default.beta - truth) < np.linalg.norm(Wb @ ident.ols().beta - truth)
    with pytest.raises(ValueError, match="weighting"):
        ident.wls("bogus")
    with pytest.raises(ValueError, match="positive"):
        ident.wls(np.array([1.0, -1.0, 1.0]))


def test_rank_deficient_trajectory_is_named(arm, base, trajectory):
    t, q, dq, ddq, W = trajectory
    q, dq, ddq = q.copy(), dq.copy(), ddq.copy()
    q[:, 2] = 0.1
    dq[:, 2] = 0.0
    ddq[:, 2] = 0.0  # the insertion joint does not move
    W = arm.regressor_batch(q, dq, ddq)
    tau = (W @ arm.true_params()).reshape(-1, 3)
    with pytest.raises(RankDeficientError, match=r"does not excite.*joint3\.Fc"):
        identification(arm, base, q, dq, ddq, W, tau)


def test_nearly_dependent_trajectory_is_named(arm, base, make_trajectory):
    # Tiny motion about one pose: the regressor is numerically rank deficient.
    t, q, dq, ddq = make_trajectory(arm, seed=2, duration=5.0, rate=50.0, fill=1e-6)
    W = arm.regressor_batch(q, dq, ddq)
    tau = (W @ arm.true_params()).reshape(-1, 3)
    with pytest.raises(RankDeficientError, match="condition number"):
        identification(arm, base, q, dq, ddq, W, tau)


def test_pseudo_inertia_is_stronger_than_eq_5_32():
    # A "body" with positive mass and positive definite inertia that breaks the triangle
    # inequality Ixx + Iyy >= Izz: eq. 5.32 accepts it, the pseudo-inertia does not.
    p = np.array([1.0, 0, 0, 0, 0.1, 0, 0.1, 0, 0, 0.5])
    D = np.diag([0.1, 0.1, 0.5, 1.0])
    assert np.linalg.eigvalsh(D).min() > 0
    assert np.linalg.eigvalsh(pseudo_inertia(p)).min() < 0
    layout = ReferenceArm().param_layout
    pi = ReferenceArm().true_params()
    pi[:10] = p
    chk = check_physical(pi, layout)
    assert not chk["pseudo_inertia_psd"]["pass"] and not chk["all_pass"]
    pi = ReferenceArm().true_params()
    pi[layout.drive_index(2, "Fv")] = -0.1
    assert not check_physical(pi, layout)["viscous_nonnegative"]["pass"]


def test_validation_errors():
    meas = np.array([[1.0, 2.0], [-1.0, 2.0]])
    pred = np.array([[1.1, 2.0], [-0.9, 1.0]])
    e = validation_errors(meas, pred)
    np.testing.assert_allclose(e["relative_error"], [np.sqrt(0.02) / np.sqrt(2), 1 / np.sqrt(8)])
    np.testing.assert_allclose(e["rms"], [0.1, np.sqrt(0.5)])


@pytest.mark.parametrize("amplitude", [0.4, -0.3])
def test_extra_column_fitted_with_its_sign_constraint(arm, base, trajectory, amplitude):
    """An extra column outside the standard parameters (a Stribeck-like bump on joint 3) is
    fitted with the base parameters: LS recovers its amplitude whatever its sign; the SDP
    recovers a positive one and holds a negative one at zero (amplitudes >= 0), and checks it."""
    t, q, dq, ddq, W = trajectory
    bump = np.zeros_like(dq)
    bump[:, 2] = np.exp(-(dq[:, 2] / 0.05) ** 2) * np.tanh(100 * dq[:, 2])
    X = bump.reshape(-1, 1)
    tau = (W @ arm.true_params()).reshape(-1, 3) + amplitude * bump
    ident = identification(arm, base, q, dq, ddq, W, tau, extra=X, extra_names=["joint3.Fst"])
    for fit in (ident.ols(), ident.wls()):
        assert fit.extra == pytest.approx([amplitude], abs=1e-6)
        assert np.allclose(fit.predict(base.regressor(W), 3, X), tau, atol=1e-6)
        with pytest.raises(ValueError, match="extra column"):
            fit.predict(base.regressor(W), 3)
    sdp = ident.sdp()
    assert sdp.extra_names == ["joint3.Fst"]
    assert sdp.checks["extra_nonnegative"]["pass"] and sdp.checks["all_pass"]
    if amplitude > 0:
        assert sdp.extra == pytest.approx([amplitude], abs=1e-4)
        assert ident.ols().checks["realizable"]["pass"]
    else:
        assert sdp.extra == pytest.approx([0.0], abs=1e-6)
        # The LS solution needs a negative amplitude: no consistent model gives its torques.
        assert not ident.ols().checks["realizable"]["pass"]
