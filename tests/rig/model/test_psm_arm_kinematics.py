import numpy as np
import pytest

from rig.model import psm_kinematics as K
from rig.model import psm_tool
from rig.model.psm_arm_kinematics import (
    IKError,
    JOINT_NAMES,
    RCM_FRAME_TO_BASE,
    RIG_TIP_TO_TOOL_TIP,
    PSMKinematics,
    adjoint,
)

KIN = PSMKinematics()
RAW = PSMKinematics(exact_right_angles=False)
ALL_TOOLS = [PSMKinematics(t) for t in psm_tool.TOOLS]


def _inside(kin, rng, margin=0.9, q3_min=0.03):
    """Random joints well inside the limits (insertion at least q3_min)."""
    mid = 0.5 * (kin.q_min + kin.q_max)
    half = 0.5 * (kin.q_max - kin.q_min) * margin
    q = rng.uniform(mid - half, mid + half)
    q[2] = rng.uniform(q3_min, kin.q_max[2] * margin)
    return q


def _vee(W):
    return np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2.0


# ------------------------------------------------------------------- the tool table

def test_tool_table_holds_the_default_and_finds_by_either_spelling():
    assert psm_tool.DEFAULT_TOOL.name == "LARGE_NEEDLE_DRIVER_400006"
    assert psm_tool.tool("LARGE_NEEDLE_DRIVER:400006") is psm_tool.DEFAULT_TOOL
    assert len(psm_tool.TOOLS) >= 5
    for name in ("PROGRASP_FORCEPS_400093", "CURVED_SCISSORS_400178",
                 "MARYLAND_BIPOLAR_FORCEPS_400172", "MEGA_NEEDLE_DRIVER_400194"):
        assert psm_tool.tool(name).name == name


def test_unknown_tool_is_one_line_naming_the_known_ones():
    with pytest.raises(ValueError) as info:
        psm_tool.tool("NEEDLE_DRIVER_400117")
    message = str(info.value)
    assert "\n" not in message
    for name in psm_tool.TOOL_NAMES:
        assert name in message


@pytest.mark.parametrize("tool", psm_tool.TOOLS, ids=lambda t: t.name)
def test_tool_data_is_consistent(tool):
    C = tool.coupling_matrix
    assert C.shape == (4, 4) and abs(np.linalg.det(C)) > 0.1
    O = tool.tooltip_offset_matrix
    assert np.allclose(O[:3, :3] @ O[:3, :3].T, np.eye(3))
    assert np.all(tool.q4_min < tool.q4_max)
    assert np.all(tool.effort4_max > 0)
    assert [row.name for row in tool.dh] == ["roll", "wrist_pitch", "wrist_yaw"]
    assert 0.005 < tool.wrist_yaw_length < 0.015
    assert len(tool.tool_engage_lower) == len(tool.tool_engage_upper) == 4


def test_joint_names_and_limits():
    assert KIN.joint_names == JOINT_NAMES == (
        "outer_yaw", "outer_pitch", "outer_insertion", "outer_roll",
        "outer_wrist_pitch", "outer_wrist_yaw")
    assert KIN.q_min.shape == KIN.q_max.shape == (6,)
    assert KIN.q_max[2] == 0.24 and KIN.q_min[2] == 0.0
    assert KIN.q_max[3] == pytest.approx(np.deg2rad(260), abs=1e-5)


# ------------------------------------------------------- today's 3-joint model and frames

def test_shaft_point_is_todays_tip_in_the_same_base_frame():
    assert np.array_equal(RCM_FRAME_TO_BASE, np.eye(4))
    rng = np.random.default_rng(1)
    lo = np.maximum(KIN.q_min[:3], K.Q_MIN)
    hi = np.minimum(KIN.q_max[:3], K.Q_MAX)
    worst = 0.0
    for _ in range(300):
        q = np.zeros(6)
        q[:3] = rng.uniform(lo, hi)
        today = (RCM_FRAME_TO_BASE @ np.append(K.tip_in_rcm(q[:3]), 1.0))[:3]
        worst = max(worst, np.abs(KIN.shaft_point(q) - today).max(),
                    np.abs(KIN.shaft_frame(q)[:3, 3] - today).max())
        # the wrist does not move the shaft end
        q[3:] = rng.uniform(KIN.q_min[3:], KIN.q_max[3:])
        worst = max(worst, np.abs(KIN.shaft_point(q) - today).max(),
                    np.abs(KIN.shaft_frame(q)[:3, 3] - today).max())
    assert worst < 1e-9


def test_todays_tip_frame_is_the_tool_tip_turned_90_deg_and_9_mm_short():
    rng = np.random.default_rng(2)
    lo = np.maximum(KIN.q_min[:3], K.Q_MIN)
    hi = np.minimum(KIN.q_max[:3], K.Q_MAX)
    Rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.array_equal(RIG_TIP_TO_TOOL_TIP[:3, :3], Rz90)
    assert np.array_equal(RIG_TIP_TO_TOOL_TIP[:3, 3], [0.0, 0.0, 0.0091])
    assert np.allclose(KIN.rig_tip_to_tool_tip, RIG_TIP_TO_TOOL_TIP, atol=1e-15)
    for _ in range(200):
        q = np.zeros(6)
        q[:3] = rng.uniform(lo, hi)
        expected = K.tip_pose_rcm(q[:3]) @ RIG_TIP_TO_TOOL_TIP
        assert np.allclose(KIN.forward(q), expected, atol=1e-12)


@pytest.mark.parametrize("kin", ALL_TOOLS, ids=lambda k: k.tool.name)
def test_tool_tip_is_the_wrist_yaw_length_beyond_the_shaft_point(kin):
    rng = np.random.default_rng(3)
    a = kin.tool.wrist_yaw_length
    if kin.tool is psm_tool.DEFAULT_TOOL:
        assert a == 0.0091
    for _ in range(50):
        q = _inside(kin, rng)
        q[3:] = 0.0
        s = kin.shaft_point(q)
        along = s / np.linalg.norm(s)
        assert np.allclose(kin.forward(q)[:3, 3], s + a * along, atol=1e-12)
        # whatever the wrist does, the tip stays a from the shaft point
        q[3:] = _inside(kin, rng)[3:]
        assert np.linalg.norm(kin.forward(q)[:3, 3] - kin.shaft_point(q)) == pytest.approx(a, abs=1e-12)
        assert np.allclose(kin.rig_tip_to_tool_tip[:3, 3], [0.0, 0.0, a], atol=1e-15)


@pytest.mark.parametrize("kin", [KIN, RAW], ids=["right-angles", "as-written"])
def test_remote_centre_of_motion_holds(kin):
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(300):
        q = rng.uniform(kin.q_min, kin.q_max)
        F = kin.frames(q)
        for i in (2, 3):  # frames 3 and 4: the shaft's axis and its end
            z, o = F[i][:3, 2], F[i][:3, 3]
            worst = max(worst, np.linalg.norm(o - (o @ z) * z))
    assert worst < 1e-12


def test_as_written_angles_differ_from_right_angles_by_microns():
    rng = np.random.default_rng(5)
    dp = dr = 0.0
    for _ in range(500):
        q = rng.uniform(KIN.q_min, KIN.q_max)
        A, B = KIN.forward(q), RAW.forward(q)
        dp = max(dp, np.linalg.norm(A[:3, 3] - B[:3, 3]))
        dr = max(dr, np.linalg.norm(_vee(A[:3, :3].T @ B[:3, :3] - np.eye(3))))
    assert 1e-7 < dp < 5e-6
    assert dr < 5e-5


def test_closed_form_equals_the_generic_chain():
    rng = np.random.default_rng(6)
    for kin in ALL_TOOLS:
        for _ in range(30):
            q = rng.uniform(kin.q_min * 1.2, kin.q_max * 1.2)
            F = kin.frames(q)
            assert np.allclose(kin.forward(q), F[6], atol=1e-14)
            T, J = kin._hybrid(q)
            kin.exact_right_angles = False
            try:
                Tg, Jg = kin._hybrid(q)
            finally:
                kin.exact_right_angles = True
            assert np.allclose(T, Tg, atol=1e-14)
            assert np.allclose(J, Jg, atol=1e-14)


# ------------------------------------------------------------------------- Jacobians

@pytest.mark.parametrize("kin", [KIN, RAW, ALL_TOOLS[1]], ids=["lnd", "as-written", "prograsp"])
def test_jacobians_match_finite_differences(kin):
    rng = np.random.default_rng(7)
    eps = 1e-6
    for _ in range(20):
        q = _inside(kin, rng)
        T = kin.forward(q)
        R, p = T[:3, :3], T[:3, 3]
        Jb_fd = np.zeros((6, 6))
        Js_fd = np.zeros((6, 6))
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = eps
            dT = (kin.forward(q + dq) - kin.forward(q - dq)) / (2 * eps)
            dp, dR = dT[:3, 3], dT[:3, :3]
            Jb_fd[:3, j] = R.T @ dp
            Jb_fd[3:, j] = _vee(R.T @ dR)
            w = _vee(dR @ R.T)
            Js_fd[3:, j] = w
            Js_fd[:3, j] = dp - np.cross(w, p)
        assert np.allclose(kin.jacobian_body(q), Jb_fd, atol=1e-8)
        assert np.allclose(kin.jacobian_spatial(q), Js_fd, atol=1e-8)


def test_spatial_is_the_adjoint_of_body_and_one_pass_agrees():
    rng = np.random.default_rng(8)
    for _ in range(50):
        q = _inside(KIN, rng)
        T, Jb, Js = KIN.forward_and_jacobians(q)
        assert np.allclose(T, KIN.forward(q), atol=1e-15)
        assert np.allclose(Jb, KIN.jacobian_body(q), atol=1e-15)
        assert np.allclose(Js, KIN.jacobian_spatial(q), atol=1e-15)
        assert np.allclose(Js, adjoint(T) @ Jb, atol=1e-14)
        # power: a body wrench and its spatial image give the same joint efforts
        wrench_b = rng.normal(size=6)
        A = adjoint(T)
        wrench_s = np.linalg.solve(A.T, wrench_b)
        assert np.allclose(Jb.T @ wrench_b, Js.T @ wrench_s, atol=1e-12)


def test_body_jacobian_rows_are_force_then_torque_in_the_tip_frame():
    # a pure insertion moves the tip along the shaft, which is +z of the tip frame at wrist 0
    q = np.array([0.2, -0.3, 0.12, 0.0, 0.0, 0.0])
    Jb = KIN.jacobian_body(q)
    assert np.allclose(Jb[:, 2], [0, 0, 1, 0, 0, 0], atol=1e-15)
    # the roll turns the tip about its own z
    assert np.allclose(Jb[3:, 3], [0, 0, 1], atol=1e-15)


# --------------------------------------------------------------------------- inverse

@pytest.mark.parametrize("kin", [KIN, RAW] + ALL_TOOLS[1:], ids=lambda k: (
    k.tool.name + ("" if k.exact_right_angles else "-as-written")))
def test_inverse_round_trip_near_and_far_seeds(kin):
    rng = np.random.default_rng(9)
    for _ in range(100):
        q = _inside(kin, rng)
        T = kin.forward(q)
        near = q + rng.normal(0.0, 0.05, 6)
        q_near = kin.inverse(T, near)
        assert np.allclose(q_near, q, atol=1e-9)
        far = _inside(kin, rng)
        q_far = kin.inverse(T, far)
        T_far = kin.forward(q_far)
        assert np.abs(T_far[:3, 3] - T[:3, 3]).max() < 1e-9
        assert np.abs(T_far[:3, :3] - T[:3, :3]).max() < 1e-9
        assert np.all(q_far >= kin.q_min - 1e-9) and np.all(q_far <= kin.q_max + 1e-9)


def test_inverse_takes_the_roll_turn_closest_to_the_seed():
    q = np.array([0.1, 0.2, 0.15, 4.0 - 2 * np.pi, 0.3, -0.2])
    T = KIN.forward(q)
    assert KIN.inverse(T, q)[3] == pytest.approx(q[3], abs=1e-12)
    seed = q.copy()
    seed[3] = 4.0
    assert KIN.inverse(T, seed)[3] == pytest.approx(4.0, abs=1e-12)
    # the closest turn to a seed beyond the limit is outside: the one inside is taken
    seed[3] = 2 * np.pi + 0.1
    q[3] = 0.1
    assert KIN.inverse(KIN.forward(q), seed)[3] == pytest.approx(0.1, abs=1e-12)


def test_out_of_reach_raises_ikerror():
    assert issubclass(IKError, ValueError)
    T = KIN.forward(np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]))
    far = T.copy()
    far[:3, 3] *= 5.0                       # insertion ~0.5 m
    with pytest.raises(IKError, match="outer_insertion"):
        KIN.inverse(far)
    rcm = T.copy()
    rcm[:3, 3] = [0.0, 0.0005, 0.0]
    with pytest.raises(IKError, match="1 mm"):
        KIN.inverse(rcm)
    # a wrist pitch of 90 degrees is beyond the large needle driver's 80
    q_bad = np.array([0.0, 0.0, 0.12, 0.0, np.pi / 2, 0.0])
    with pytest.raises(IKError, match="outer_wrist_pitch"):
        KIN.inverse(KIN.frames(q_bad)[6], np.zeros(6))
    q_bad = np.array([1.7, 0.0, 0.12, 0.0, 0.0, 0.0])  # yaw beyond 1.588
    with pytest.raises(IKError, match="outer_yaw"):
        KIN.inverse(KIN.frames(q_bad)[6])


def test_inverse_keeps_the_dvrk_safe_distance_when_asked():
    q = np.array([0.2, 0.1, 0.04, 0.3, 0.2, -0.1])   # shaft end 0.024 m from the RCM
    T = KIN.forward(q)
    assert np.linalg.norm(KIN.shaft_point(q)) < psm_tool.SAFE_DISTANCE_FROM_RCM
    plain = KIN.inverse(T, q)
    assert np.allclose(plain, q, atol=1e-12)
    deep = q.copy()
    deep[2] = 0.10                          # coming from deeper: stop at the safe distance
    guarded = KIN.inverse(T, deep, keep_safe_distance=True)
    assert np.linalg.norm(KIN.shaft_point(guarded)) == pytest.approx(psm_tool.SAFE_DISTANCE_FROM_RCM)
    shallow = q.copy()
    shallow[2] = 0.03                       # already too close: never closer than now
    guarded = KIN.inverse(T, shallow, keep_safe_distance=True)
    assert guarded[2] == pytest.approx(0.04)
