import numpy as np
import pytest

from rig.model import psm_kinematics as K


def _grid(n=9):
    q1 = np.linspace(K.Q_MIN[0], K.Q_MAX[0], n)
    q2 = np.linspace(K.Q_MIN[1], K.Q_MAX[1], n)
    return [(a, b) for a in q1 for b in q2]


def test_beta_satisfies_its_equation():
    # a3 sin(beta) - a5 cos(beta) = -a6 (RCM exact) with the tool perpendicular to the yaw axis
    assert K.A3 * np.sin(K.BETA) - K.A5 * np.cos(K.BETA) == pytest.approx(-K.A6, abs=1e-15)
    assert 1.0 < K.BETA < 1.5


@pytest.mark.parametrize("q3", [0.0, 0.12, 0.24])
def test_tool_axis_passes_through_one_point(q3):
    rcm = K.RCM_FRAME[:3, 3]
    worst = 0.0
    for q1, q2 in _grid():
        T = K.frames(np.array([q1, q2, q3]))
        p, z = T["6"][:3, 3], T["6"][:3, 2]
        d = rcm - p
        worst = max(worst, np.linalg.norm(d - (d @ z) * z))
        # the tip lies on that axis too
        e = T["tip"][:3, 3] - rcm
        worst = max(worst, np.linalg.norm(e - (e @ z) * z))
    assert worst < 1e-9


def test_rcm_is_on_the_yaw_axis_and_tool_perpendicular_at_zero_pitch():
    T = K.frames(np.array([0.3, 0.0, 0.1]))
    z1, o1 = T["1"][:3, 2], T["1"][:3, 3]
    d = K.RCM_FRAME[:3, 3] - o1
    assert np.linalg.norm(d - (d @ z1) * z1) < 1e-12
    assert abs(T["6"][:3, 2] @ z1) < 1e-12


def test_tip_matches_dvrk_rcm_kinematics():
    rng = np.random.default_rng(3)
    for _ in range(200):
        q = rng.uniform(K.Q_MIN, K.Q_MAX)
        tip = (K.RCM_FRAME_INV @ K.frames(q)["tip"])[:3, 3]
        r = q[2] - K.L_RCC + K.L_TOOL
        expected = r * np.array([np.cos(q[1]) * np.sin(q[0]), -np.sin(q[1]), -np.cos(q[0]) * np.cos(q[1])])
        assert np.allclose(tip, expected, atol=1e-12)
        assert np.allclose(K.tip_in_rcm(q), expected, atol=1e-12)


def test_fk_ik_round_trip():
    rng = np.random.default_rng(4)
    for _ in range(200):
        q = rng.uniform(K.Q_MIN + [0, 0, 0.02], K.Q_MAX)
        assert np.allclose(K.ik_rcm(K.tip_in_rcm(q)), q, atol=1e-10)


def test_ik_refuses_unreachable_targets():
    with pytest.raises(K.IKError, match="joint 3"):
        K.ik_rcm(np.array([0.0, 0.0, -0.5]))
    with pytest.raises(K.IKError, match="RCM"):
        K.ik_rcm(np.zeros(3))


@pytest.mark.parametrize("frame", ["2", "3", "4", "5", "6", "7", "tip", "C1", "C2-int", "C2"])
def test_geometric_jacobian_matches_finite_differences(frame):
    rng = np.random.default_rng(5)
    eps = 1e-6
    for _ in range(5):
        q = rng.uniform(K.Q_MIN, K.Q_MAX)
        J = K.geometric_jacobian(q, frame)
        for j in range(3):
            dqv = np.zeros(3)
            dqv[j] = eps
            Tp, Tm = K.frames(q + dqv)[frame], K.frames(q - dqv)[frame]
            dp = (Tp[:3, 3] - Tm[:3, 3]) / (2 * eps)
            dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * eps)
            W = dR @ K.frames(q)[frame][:3, :3].T
            omega = np.array([W[2, 1], W[0, 2], W[1, 0]])
            assert np.allclose(J[:3, j], dp, atol=1e-7)
            assert np.allclose(J[3:, j], omega, atol=1e-7)


def test_analytic_jacobian_matches_euler_angle_differences():
    q = np.array([0.3, -0.4, 0.15])
    Ja = K.analytic_jacobian(q)
    eps = 1e-6
    for j in range(3):
        dqv = np.zeros(3)
        dqv[j] = eps
        ep = K.euler_zyx(K.frames(q + dqv)["tip"][:3, :3])
        em = K.euler_zyx(K.frames(q - dqv)["tip"][:3, :3])
        assert np.allclose(Ja[3:, j], (ep - em) / (2 * eps), atol=1e-7)


def test_tip_jacobian_closed_form():
    rng = np.random.default_rng(6)
    q = rng.uniform(K.Q_MIN, K.Q_MAX)
    J = K.tip_jacobian_rcm(q)
    Jg = K.RCM_FRAME_INV[:3, :3] @ K.geometric_jacobian(q)[:3]
    assert np.allclose(J, Jg, atol=1e-12)


def test_joint_limits_of_table_4_2():
    lim = K.JointLimits()
    assert lim.violation(np.array([0.0, 0.0, 0.1]), np.array([1.0, 1.0, 0.1])) is None
    assert "joint 1 position" in lim.violation(np.array([1.6, 0.0, 0.1]))
    assert "joint 2 velocity" in lim.violation(np.zeros(3) + [0, 0, 0.1], np.array([0.0, 2.5, 0.0]))
    assert K.DQ_MAX.tolist() == [2.0, 2.0, 0.4]
