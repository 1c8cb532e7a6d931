"""The external-force estimate (issue 47) against the simulated rig's known truth: an object
(a spring of known stiffness) between two simulated PSMs pulls on PSM1's tip with the
tension the world computes; the estimate from PSM1's measured joints and efforts alone
(momentum observer on the arm's model, J^-T) must find that force."""

import numpy as np
import pytest

from calibration.momentum_observer import MomentumObserver, observe
from calibration.tip_force import FLAGS, TipForceEstimator, base_jacobian, estimate_recording, tip_force
from rig.model import psm_kinematics as K
from rig.model.psm_dynamics import PSMDynamics
from rig.sim.world import ArmSpec, ObjectSpec, SimWorld

DT = 0.002     # the estimate's sample interval (s): every second world step
Q0 = np.array([0.0, 0.0, 0.12])


def _facing(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    T[:2, :2] = [[-1.0, 0.0], [0.0, -1.0]]
    return T


def _world(stretch: float, seed: int = 1) -> SimWorld:
    w = SimWorld([ArmSpec("PSM1", q0=Q0), ArmSpec("PSM2", base=_facing(1.0728), q0=Q0)], None, seed=seed)
    if stretch is not None:
        d0 = float(np.linalg.norm(w.tip_world("PSM2") - w.tip_world("PSM1")))
        w.attach_object(ObjectSpec(("PSM1", "PSM2"), 2450.0, 5.0, d0 - stretch, "spring"))
    return w


def _motion(s: float) -> tuple[np.ndarray, np.ndarray]:
    """PSM1's joint path: every joint swinging (rad, rad, m), well away from zero speed most of the time."""
    amp, f = np.array([0.08, 0.06, 0.02]), np.array([0.4, 0.3, 0.5])
    return Q0 + amp * np.sin(2 * np.pi * f * s), amp * 2 * np.pi * f * np.cos(2 * np.pi * f * s)


def _run(w: SimWorld, seconds: float, moving_from: float):
    """Step the world; PSM1 follows `_motion` after `moving_from` s under its PID, PSM2 holds.
    Returns per estimate sample: time, estimated force, true force on PSM1's tip (N,
    frame 0 = world here), flags."""
    est = TipForceEstimator(PSMDynamics(), sigma=[0.03, 0.07, 0.1])
    rows = []
    for k in range(int(round(seconds / w.dt))):
        t = k * w.dt
        if t >= moving_from:
            w.servo_jp("PSM1", *_motion(t - moving_from))
        w.step()
        if k % 2:
            continue
        q, dq, tau = w.measured_js("PSM1")
        s = est.update(q, dq, tau, DT)
        p1, p2 = w.tip_world("PSM1"), w.tip_world("PSM2")
        d = p2 - p1
        true = w.tension(0) * d / np.linalg.norm(d) if w.object is not None else np.zeros(3)
        rows.append((t, s.force, true, s))
    t = np.array([r[0] for r in rows])
    return t, np.array([r[1] for r in rows]), np.array([r[2] for r in rows]), [r[3] for r in rows], est


def _lowpass(x: np.ndarray, gain: float) -> np.ndarray:
    """The observer's own first-order filter (bandwidth `gain` rad/s) applied to the truth."""
    out = np.empty_like(x)
    out[0] = x[0]
    a = 1.0 - np.exp(-gain * DT)
    for k in range(1, len(x)):
        out[k] = out[k - 1] + a * (x[k] - out[k - 1])
    return out


@pytest.fixture(scope="module")
def pulled():
    return _run(_world(stretch=0.002), seconds=3.0, moving_from=0.8)


def test_base_jacobian_is_the_models_tip_jacobian():
    dyn = PSMDynamics()
    for q in ([0.3, -0.2, 0.15], [-0.5, 0.4, 0.08], [0.0, 0.0, 0.2]):
        np.testing.assert_allclose(base_jacobian(np.array(q)), dyn.tip_jacobian(np.array(q))[:3], atol=1e-9)


def test_tip_force_inverts_the_jacobian_transpose():
    q = np.array([0.2, -0.3, 0.14])
    F = np.array([1.0, -2.0, 0.5])
    tau = base_jacobian(q).T @ F
    np.testing.assert_allclose(tip_force(q, tau), F, atol=1e-12)


def test_observer_finds_a_known_joint_torque_on_the_models_own_motion():
    # Efforts generated from the model itself plus a known external joint torque: the
    # observer returns that torque through its first-order filter, with no acceleration given.
    dyn = PSMDynamics()
    rate, n = 1000.0, 3000
    t = np.arange(n) / rate
    q = Q0 + np.column_stack([0.2 * np.sin(2 * t), 0.15 * np.sin(1.5 * t), 0.03 * np.sin(2.5 * t)])
    dq = np.column_stack([0.4 * np.cos(2 * t), 0.225 * np.cos(1.5 * t), 0.075 * np.cos(2.5 * t)])
    ddq = np.column_stack([-0.8 * np.sin(2 * t), -0.3375 * np.sin(1.5 * t), -0.1875 * np.sin(2.5 * t)])
    ext = np.array([0.3, -0.2, 1.5]) * (t[:, None] > 1.0)
    tau = np.array([dyn.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(n)]) - ext
    r = observe(dyn, None, q, dq, tau, rate, gain=50.0)
    late = t > 1.3     # 15 time constants after the step
    np.testing.assert_allclose(r[late], ext[late], atol=0.01)
    assert np.all(np.abs(r[t < 0.99]) < 0.01)


def test_observer_rejects_a_bad_gain_and_time_running_backwards():
    with pytest.raises(ValueError):
        MomentumObserver(PSMDynamics(), gain=0.0)
    obs = MomentumObserver(PSMDynamics())
    obs.update(Q0, np.zeros(3), np.zeros(3), 0.001)
    with pytest.raises(ValueError):
        obs.update(Q0, np.zeros(3), np.zeros(3), 0.0)


def test_estimate_finds_the_springs_pull_while_the_arm_moves(pulled):
    t, est, true, samples, estimator = pulled
    moving = t > 1.2
    want = _lowpass(true, float(estimator.observer.gain[0]))
    err = est[moving] - want[moving]
    assert np.mean(np.linalg.norm(true[moving], axis=1)) > 3.0          # a real pull: 3-7 N
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    assert np.all(rms < 0.3), rms
    # the pull along the object (x), the tension itself, within 0.9 N at the worst sample (reversals)
    assert np.max(np.abs(err[:, 0])) < 0.9, np.max(np.abs(err[:, 0]))
    # and without the object the same motion gives no force
    t0, est0, _, _, _ = _run(_world(stretch=None), seconds=2.0, moving_from=0.5)
    assert np.sqrt(np.mean(est0[t0 > 0.9] ** 2)) < 0.3


def test_estimate_at_rest_is_flagged_and_its_spread_covers_the_error(pulled):
    t, est, true, samples, _ = pulled
    rest = (t > 0.4) & (t < 0.8)     # both arms held, the spring pulling: every joint stuck
    assert all(samples[k].flags["joint3_static"] for k in np.flatnonzero(rest))
    err = est[rest] - true[rest]
    spread = np.array([np.sqrt(np.diag(samples[k].covariance)) for k in np.flatnonzero(rest)])
    # joint 3's static band widens the spread; the error stays inside three spreads
    assert np.all(np.abs(err) < 3 * spread), (np.abs(err).max(0), spread.min(0))
    moving = np.flatnonzero(t > 1.2)
    assert not all(samples[k].flags["joint3_static"] for k in moving)


def test_flags_mark_a_joint_at_its_limit_and_a_singular_jacobian():
    est = TipForceEstimator(PSMDynamics(), sigma=[0.03, 0.07, 0.1])
    s = est.update(np.array([K.Q_MAX[0] - 0.005, 0.0, 0.12]), np.array([0.1, 0.1, 0.05]), np.zeros(3), DT)
    assert s.flags["at_limit"] and not s.flags["joint3_static"]
    # the tip at the remote centre: q3 = L_RCC - L_TOOL gives r = 0
    s = est.update(np.array([0.0, 0.0, K.L_RCC - K.L_TOOL + 1e-4]), np.array([0.1, 0.1, 0.05]), np.zeros(3), DT)
    assert s.flags["singular"]


def test_recording_estimate_returns_its_columns():
    dyn = PSMDynamics()
    n = 400
    q = np.tile(Q0, (n, 1))
    tau = np.tile(dyn.inverse_dynamics(Q0, np.zeros(3), np.zeros(3), friction=False), (n, 1))
    rec = estimate_recording(dyn, None, q, np.zeros((n, 3)), tau, 200.0, sigma=[0.03, 0.07, 0.1])
    assert rec.force.shape == (n, 3) and rec.flags.shape == (n, len(FLAGS))
    assert np.all(rec.flags[:, FLAGS.index("joint3_static")])
    # held at rest by its weight's torque alone: the model's friction offset Fo is missing from
    # the effort, so something outside must supply it (tau_ext = g + f - tau = Fo)
    np.testing.assert_allclose(rec.force[-1], tip_force(Q0, dyn.Fo), atol=1e-6)
