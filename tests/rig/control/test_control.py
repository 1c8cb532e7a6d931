"""Controllers of thesis chapter 7 (rig.control.controllers): filters, friction compensation, impedance."""

import numpy as np
import pytest

from rig.control.controllers import FeedforwardModel, Impedance, KalmanDifferentiator, StickSlipCompensation
from rig.model import psm_kinematics as K
from rig.model.psm_dynamics import PSMDynamics

FC, FV, FO = np.array([0.3, 0.4, 0.5]), np.array([0.2, 0.3, 0.6]), np.array([0.01, -0.02, 0.1])


def _comp(**kw):
    return StickSlipCompensation(FC.copy(), FV.copy(), FO.copy(), 400.0, Fs_pos=1.1, Fs_neg=-0.9, **kw)


def _coulomb_viscous(j, v):
    return FC[j] * np.tanh(200.0 * v) + FV[j] * v + FO[j]


def test_kalman_differentiator_recovers_a_ramp_and_reports_its_lag():
    f = KalmanDifferentiator(1, 1e-3, 1e-4, 5.0)
    rng = np.random.default_rng(1)
    for k in range(3000):
        value, rate = f.update(np.array([0.2 * k * 1e-3 + rng.normal(0, 1e-4)]))
    # a constant-acceleration filter follows a ramp without bias: what is left is the noise
    # its gain passes, within four of its standard deviations
    sd_value, sd_rate = f.noise_gain(value_noise=1e-4)
    assert rate[0] == pytest.approx(0.2, abs=4 * sd_rate)
    assert value[0] == pytest.approx(0.2 * 2999e-3, abs=4 * sd_value)
    assert sd_value < 1e-4                    # it does filter
    lag_value, lag_rate = f.delay(2.0)
    assert abs(lag_value) < 1e-3 and 0.0 < lag_rate < 0.05   # the rate lags, the value hardly


@pytest.mark.parametrize("dt, value_noise, process_noise, rate_noise", [
    (1e-3, 1e-4, 5.0, None), (1 / 200, 0.02, 200.0, None), (1 / 500, 6e-6, 20.0, 2e-3)])
def test_kalman_gain_is_the_one_filterpy_converges_to(dt, value_noise, process_noise, rate_noise):
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import KalmanFilter

    f = KalmanDifferentiator(1, dt, value_noise, process_noise, rate_noise=rate_noise)
    m = 1 if rate_noise is None else 2
    kf = KalmanFilter(dim_x=3, dim_z=m)
    kf.F, kf.H = f.F.copy(), np.eye(3)[:m]
    kf.R = np.diag([value_noise ** 2] + ([] if rate_noise is None else [rate_noise ** 2]))
    kf.Q = Q_discrete_white_noise(dim=3, dt=dt, var=process_noise ** 2)
    for _ in range(20000):
        kf.predict()
        kf.update(np.zeros(m))
    np.testing.assert_allclose(f.gains[0], kf.K, rtol=1e-6, atol=1e-12)


def test_kalman_step_matches_filterpy_and_coasts_on_a_view_of_its_own_state():
    from filterpy.kalman import KalmanFilter

    f = KalmanDifferentiator(2, 1e-3, [1e-4, 2e-4], [5.0, 50.0], rate_noise=[1e-2, 3e-2])
    f.reset(np.array([0.1, -0.2]), np.array([0.5, 0.0]))
    f.x[:, 2] = [1.0, -3.0]
    # one step is filterpy's predict and update with the converged gain
    kf = KalmanFilter(dim_x=3, dim_z=2)
    kf.F, kf.H = f.F, np.eye(3)[:2]
    z = np.array([[0.1006, 0.52], [-0.1999, 0.01]])
    expect = []
    for i in range(2):
        kf.x = f.x[i].copy()
        kf.predict()
        expect.append(kf.x + f.gains[i] @ (z[i] - kf.H @ kf.x))
    value, rate = f.update(z[:, 0], z[:, 1])
    np.testing.assert_allclose(f.x, expect, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.c_[value, rate], np.array(expect)[:, :2], rtol=1e-12, atol=1e-15)
    # fed a view of its own value (no new sample: the cooperative force filter), the step
    # is the prediction alone: the innovation it sees is zero
    before = f.x.copy()
    value, rate = f.update(f.x[:, 0], f.x[:, 1])
    np.testing.assert_allclose(f.x, before @ f.F.T, rtol=1e-12, atol=1e-15)


def test_moving_joints_get_coulomb_and_viscous_and_still_ones_only_the_offset():
    c = _comp()
    dq = np.array([0.05, -0.02, 0.0])
    f = c(dq, 0.0)
    assert f[0] == pytest.approx(_coulomb_viscous(0, 0.05))
    assert f[1] == pytest.approx(_coulomb_viscous(1, -0.02))
    assert f[2] == pytest.approx(FO[2])      # joint 3 still, inside the position deadband


def test_the_moving_state_has_hysteresis_so_noise_at_the_deadband_cannot_flick_it():
    c = _comp()
    db = c.velocity_deadband[2]
    assert c(np.array([0, 0, 0.6 * db]), 0.0)[2] == pytest.approx(FO[2])        # not yet moving
    assert c(np.array([0, 0, 1.1 * db]), 0.0)[2] == pytest.approx(_coulomb_viscous(2, 1.1 * db))
    # once moving it stays so down to half the deadband ...
    assert c(np.array([0, 0, 0.6 * db]), 0.0)[2] == pytest.approx(_coulomb_viscous(2, 0.6 * db))
    # ... and stops below it
    assert c(np.array([0, 0, 0.4 * db]), 0.0)[2] == pytest.approx(FO[2])


def test_breakaway_force_is_a_schmitt_trigger_on_the_position_error():
    c = _comp()
    pdb = c.position_deadband
    still = np.zeros(3)
    assert c(still, 0.5 * pdb)[2] == pytest.approx(FO[2])          # inside: nothing
    assert c(still, 1.5 * pdb)[2] == pytest.approx(FO[2] + 1.1)    # leaves it: Fs+
    assert c(still, 0.5 * pdb)[2] == pytest.approx(FO[2] + 1.1)    # held while the error keeps its sign
    assert c(still, -0.1 * pdb)[2] == pytest.approx(FO[2])         # released when it crosses zero
    assert c(still, -1.5 * pdb)[2] == pytest.approx(FO[2] - 0.9)   # Fs- the other way
    # a joint that moves drops the breakaway force at once
    assert c(np.array([0, 0, -0.02]), -1.5 * pdb)[2] == pytest.approx(_coulomb_viscous(2, -0.02))


def test_a_moving_reference_sets_the_friction_of_a_joint_still_at_rest():
    c = _comp()
    ref = np.array([0.03, 0.0, -0.004])
    f = c(np.zeros(3), 5 * c.position_deadband, ref)
    assert f[0] == pytest.approx(_coulomb_viscous(0, 0.03))
    assert f[1] == pytest.approx(FO[1])
    # the reference, not the stiction logic, decides joint 3 (its error says the other way)
    assert f[2] == pytest.approx(_coulomb_viscous(2, -0.004))


def test_impedance_at_rest_is_the_model_plus_the_spring_through_the_jacobian():
    dyn = PSMDynamics()
    comp = _comp()
    comp.Fo = np.zeros(3)
    imp = Impedance(FeedforwardModel(dyn), comp, None, np.array([300.0, 300.0, 300.0]), np.zeros(3), None)
    q = np.array([0.1, -0.2, 0.14])
    x = K.tip_in_rcm(q)
    e = np.array([0.002, -0.001, 0.0005])
    tau = imp(q, np.zeros(3), x + e, np.zeros(3), np.zeros(3), np.zeros(3))
    J = K.tip_jacobian_rcm(q)
    expected = dyn.inverse_dynamics(q, np.zeros(3), np.zeros(3), friction=False) + J.T @ (300.0 * e)
    # joint 3's stiction: the target is 0.5 mm out along the tool, beyond the deadband
    expected[2] += comp.Fs_pos if (np.linalg.norm(x + e) - np.linalg.norm(x)) > 0 else comp.Fs_neg
    assert tau == pytest.approx(expected, abs=1e-9)


def test_impedance_stiction_acts_on_the_rest_position_not_the_target():
    """In contact the target is never reached: the measured force displaces the rest
    position, and with the two balanced no breakaway force is applied."""
    dyn = PSMDynamics()
    Kp = np.array([200.0, 200.0, 200.0])
    imp = Impedance(FeedforwardModel(dyn), _comp(), None, Kp, np.zeros(3), None)
    q = np.array([0.0, 0.0, 0.15])
    x = K.tip_in_rcm(q)
    axis = x / np.linalg.norm(x)
    h = 5.0 * axis                         # the tip pushes 5 N along the tool
    target = x + h / Kp                    # 25 mm further: where the spring balances it
    J = K.tip_jacobian_rcm(q)
    tau = imp(q, np.zeros(3), target, np.zeros(3), np.zeros(3), h)
    spring_only = dyn.inverse_dynamics(q, np.zeros(3), np.zeros(3), friction=False) + J.T @ (Kp * (target - x))
    assert tau[2] - spring_only[2] == pytest.approx(FO[2], abs=1e-9)


@pytest.mark.parametrize("value_noise, process_noise, rate_noise", [
    ([6e-6, 6e-6, 1e-6], [20.0, 20.0, 5.0], [2e-3, 2e-3, 3e-4]),   # the cooperative's joint filter
    (0.02, 200.0, None)])                                          # and its tension filter
def test_samples_at_any_interval_keep_the_filter_stable(value_noise, process_noise, rate_noise):
    """From a tenth of the nominal interval to LONGEST of them, the filter's step is a
    contraction (the prediction over the interval, the gain of that interval); a gain of a
    shorter interval with the longer prediction diverged (spectral radius 1.5-21)."""
    n = 3 if rate_noise is not None else 1
    f = KalmanDifferentiator(n, 0.01, value_noise, process_noise, rate_noise=rate_noise)
    for k in range(1, int(10 * f.LONGEST) + 1):
        Ft, g0, g1 = f._form(k * f.dt / 10.0)
        for i in range(n):
            K = g0[i][:, None] if g1 is None else np.stack([g0[i], g1[i]], axis=1)
            A = (np.eye(3) - K @ f.H) @ Ft.T
            assert np.max(np.abs(np.linalg.eigvals(A))) < 1.0, (k, i)


def test_a_ramp_sampled_at_irregular_intervals_and_a_long_gap():
    f = KalmanDifferentiator(1, 0.01, 1e-5, 20.0, rate_noise=2e-3)
    rng = np.random.default_rng(4)
    t = 0.0
    for _ in range(400):
        dt = 0.01 * rng.choice([0.4, 0.6, 1.0, 1.4, 2.0, 6.0])
        t += dt
        value, rate = f.update(np.array([0.3 * t + rng.normal(0, 1e-5)]), np.array([0.3 + rng.normal(0, 2e-3)]), dt=dt)
        assert abs(rate[0] - 0.3) < 0.02, (t, rate)
    # a gap longer than LONGEST intervals restarts the filter on the sample
    value, rate = f.update(np.array([5.0]), np.array([-1.0]), dt=0.01 * (f.LONGEST + 1))
    assert value[0] == 5.0 and rate[0] == -1.0
