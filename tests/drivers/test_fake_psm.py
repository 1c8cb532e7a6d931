"""The whole simulated dVRK PSM (drivers.arm.fake_psm) in-process: its control modes against the
dVRK's semantics and its numbers against the kinematics (rig.model.psm_arm_kinematics). Over the
wire, with the dVRK's own client: tests/hil/test_dvrk_client.py."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.arm.fake_arm_state import FakeArmState
from drivers.arm.fake_psm import Impedance, FakePSM
from rig import config
from rig.devices.clock import SimClock
from rig.model.psm_arm_kinematics import PSMKinematics
from rig.sim.world import world_from_config


class _Rig:
    def __init__(self):
        self.world = world_from_config(config.load(None), arms=["PSM1"], with_object=False)
        self.clock = SimClock(self.world)
        self.psm = FakePSM(self.world, "PSM1", self.clock)
        self.state = FakeArmState(self.psm)
        self.kin = PSMKinematics()

    @property
    def t(self) -> float:
        return self.world.t

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / self.world.dt))):
            self.psm.control(self.world.t)
            self.clock.tick()
            self.psm.step_wrist()
            self.state.step(self.world.t)

    def q(self) -> np.ndarray:
        return self.psm.measured_js()[0]

    def do(self, what: str, act, moving: bool = False) -> bool:
        return self.state.motion(what, self.t, act, moving=moving)

    def until_idle(self, limit: float = 10.0) -> float:
        t0 = self.t
        while self.state.is_busy:
            assert self.t - t0 < limit, "still busy"
            self.run(0.002)
        return self.t - t0


@pytest.fixture
def rig():
    r = _Rig()
    r.state.command("home", r.t)
    r.run(2.5)
    assert r.state.ready
    return r


def test_measured_js_has_six_joints_and_the_jaw_and_cp_is_the_tool_tip(rig):
    q, dq, effort = rig.psm.measured_js()
    assert q.shape == dq.shape == effort.shape == (7,)
    T = rig.psm.measured_cp()
    np.testing.assert_allclose(T, rig.kin.forward(q[:6]), atol=1e-12)
    # the tip is the wrist-yaw length (9.1 mm for the large needle driver) past the shaft end
    assert np.linalg.norm(T[:3, 3] - rig.kin.shaft_point(q[:6])) == pytest.approx(0.0091, abs=1e-9)


def test_move_jp_busy_rises_and_falls_even_for_a_move_to_where_the_arm_is(rig):
    rig.state.events.clear()
    assert rig.do("move_jp", lambda: rig.psm.move_jp(rig.psm.setpoint_js()[0][:6]), moving=True)
    assert rig.state.is_busy
    rig.run(0.002)
    assert not rig.state.is_busy
    busy = [e.is_busy for e in rig.state.events]
    assert busy == [True, False]  # two events, one each way


def test_move_jp_moves_all_six_joints_synchronised_and_clips_to_the_limits(rig):
    goal = np.array([0.3, -0.2, 0.15, 1.0, 0.5, -0.4])
    assert rig.do("move_jp", lambda: rig.psm.move_jp(goal), moving=True)
    rig.until_idle()
    np.testing.assert_allclose(rig.psm.setpoint_js()[0][:6], goal, atol=1e-12)
    rig.run(1.0)
    assert np.all(np.abs(rig.q()[:6] - goal) <= [3e-3, 3e-3, 1e-3, 0.02, 0.02, 0.02])
    beyond = goal.copy()
    beyond[4] = 3.0  # wrist pitch: limit 1.396 rad
    rig.do("move_jp", lambda: rig.psm.move_jp(beyond), moving=True)
    rig.until_idle()
    assert rig.psm.setpoint_js()[0][4] == pytest.approx(rig.kin.q_max[4])


def test_move_cp_reaches_the_pose_through_the_inverse_kinematics(rig):
    T0 = rig.psm.measured_cp()
    goal = T0.copy()
    goal[:3, 3] += [0.02, -0.01, 0.01]
    assert rig.do("move_cp", lambda: rig.psm.move_cp(goal), moving=True)
    rig.until_idle()
    rig.run(1.0)
    T = rig.psm.measured_cp()
    np.testing.assert_allclose(T[:3, 3], goal[:3, 3], atol=1.5e-3)
    np.testing.assert_allclose(T[:3, :3], goal[:3, :3], atol=0.02)


def test_cartesian_commands_need_the_tool_past_the_cannula(rig):
    rig.do("move_jp", lambda: rig.psm.move_jp([0.0, 0.0, 0.03, 0.0, 0.0, 0.0]), moving=True)
    rig.until_idle()
    rig.run(0.5)
    rig.psm.messages.clear()
    T = rig.psm.measured_cp()
    rig.do("move_cp", lambda: rig.psm.move_cp(T), moving=True)
    warnings = [t for lvl, t in rig.psm.messages if lvl == "warning"]
    assert warnings == ["PSM1: tool/endoscope needs to be inserted past the cannula to switch to cartesian space"]
    assert rig.psm.space == "joint"


def test_servo_cp_follows_a_stream_of_poses(rig):
    T0 = rig.psm.measured_cp()
    for k in range(1, 501):
        goal = T0.copy()
        goal[:3, 3] += [0.02 * k / 500, 0.0, 0.0]
        rig.do("servo_cp", lambda g=goal: rig.psm.servo_cp(g))
        rig.run(0.002)
    rig.run(0.5)
    np.testing.assert_allclose(rig.psm.measured_cp()[:3, 3], T0[:3, 3] + [0.02, 0.0, 0.0], atol=1.5e-3)


def test_wrenches_go_to_the_joints_through_the_jacobians(rig):
    q = rig.q()[:6]
    w = np.array([1.0, -0.5, 0.8, 0.01, -0.02, 0.005])
    rig.do("spatial_servo_cf", lambda: rig.psm.servo_cf(w, kind="spatial"))
    rig.psm.control(rig.t)
    applied = rig.world.tau_cmd[rig.world.arms["PSM1"].sl]
    np.testing.assert_allclose(applied, (rig.kin.jacobian_spatial(q).T @ w)[:3], atol=1e-9)
    rig.do("body_servo_cf", lambda: rig.psm.servo_cf(w, kind="body"))
    rig.psm.control(rig.t)
    applied = rig.world.tau_cmd[rig.world.arms["PSM1"].sl]
    np.testing.assert_allclose(applied, (rig.kin.jacobian_body(q).T @ w)[:3], atol=1e-9)


def test_servo_ci_is_a_spring_about_the_goal(rig):
    """A stiff impedance (the dVRK's osaCartesianImpedanceController: p < 0 restores) about
    the present pose, then about a point 5 mm off: the tip's rest moves with the goal. The
    rest itself sits off the goal by the arm's residual over the stiffness (friction
    offsets the nominal gravity compensation does not know: about 3-4 N at the tip)."""
    rig.psm.use_gravity_compensation(True)
    T0 = rig.psm.measured_cp()
    zero = np.zeros(3)
    k = np.full(3, -1000.0)
    gains = {"position_positive": (k, np.full(3, -25.0), zero, zero),
             "position_negative": (k, np.full(3, -25.0), zero, zero),
             "orientation_positive": (np.full(3, -0.05), np.full(3, -0.001), zero, zero),
             "orientation_negative": (np.full(3, -0.05), np.full(3, -0.001), zero, zero)}
    rest = []
    for offset in ([0.0, 0.0, 0.0], [0.005, 0.0, 0.0]):
        goal = T0[:3, 3] + offset
        imp = Impedance(goal, np.eye(3), T0[:3, :3], gains)
        T = rig.psm.measured_cp()
        f = imp.wrench(T, zero, zero)[:3]
        np.testing.assert_allclose(f, k * (T[:3, 3] - goal), atol=1e-12)
        rig.do("servo_ci", lambda i=imp: rig.psm.servo_ci(i))
        rig.run(2.0)
        rest.append(rig.psm.measured_cp()[:3, 3])
    assert np.linalg.norm(rest[0] - T0[:3, 3]) < 0.006
    # within the arm's friction band (about 2 N at the tip: 2 mm on 1000 N/m)
    moved = rest[1] - rest[0]
    assert abs(moved[0] - 0.005) < 3e-3 and np.all(np.abs(moved[1:]) < 1e-3), moved


def test_deadband_and_bias_of_the_impedance(rig):
    zero = np.zeros(3)
    dead = np.array([0.002, 0.0, 0.0])
    bias = np.array([0.5, 0.0, 0.0])
    gains = {"position_positive": (np.full(3, -100.0), zero, bias, dead),
             "position_negative": (np.full(3, -100.0), zero, -bias, dead),
             "orientation_positive": (zero, zero, zero, zero), "orientation_negative": (zero, zero, zero, zero)}
    imp = Impedance(np.zeros(3), np.eye(3), np.eye(3), gains)
    T = np.eye(4)
    T[0, 3] = 0.001  # inside the deadband: the bias only
    assert imp.wrench(T, zero, zero)[0] == pytest.approx(0.5)
    T[0, 3] = 0.005  # 3 mm past the deadband
    assert imp.wrench(T, zero, zero)[0] == pytest.approx(-100.0 * 0.003 + 0.5)
    T[0, 3] = -0.005
    assert imp.wrench(T, zero, zero)[0] == pytest.approx(100.0 * 0.003 - 0.5)


def test_gravity_compensation_adds_the_nominal_gravity_torque(rig):
    from rig.model.psm_dynamics import PSMDynamics

    rig.do("servo_jf", lambda: rig.psm.servo_jf(np.zeros(6)))
    rig.psm.use_gravity_compensation(True)
    rig.psm.control(rig.t)
    q = rig.world.measured_js("PSM1")[0]
    applied = rig.world.tau_cmd[rig.world.arms["PSM1"].sl]
    np.testing.assert_allclose(applied, PSMDynamics().gravity_torque(q), atol=1e-12)


def test_jaw_moves_on_its_own_and_busy_covers_it(rig):
    assert rig.do("jaw_move_jp", lambda: rig.psm.jaw_move_jp([np.radians(60.0)]), moving=True)
    assert rig.state.is_busy
    rig.until_idle()
    rig.run(0.5)
    assert rig.psm.measured_js()[0][6] == pytest.approx(np.radians(60.0), abs=0.02)
    q_arm = rig.psm.setpoint_js()[0][:6]
    rig.do("jaw_servo_jp", lambda: rig.psm.jaw_servo_jp([0.3]))
    rig.run(0.5)
    assert rig.psm.measured_js()[0][6] == pytest.approx(0.3, abs=0.02)
    np.testing.assert_allclose(rig.psm.setpoint_js()[0][:6], q_arm, atol=1e-12)  # the arm kept its goal


def test_not_ready_arm_drops_every_command_with_the_dvrks_warning():
    r = _Rig()
    assert not r.do("servo_cp", lambda: r.psm.servo_cp(np.eye(4)))
    assert not r.do("jaw_move_jp", lambda: r.psm.jaw_move_jp([0.5]), moving=True)
    warnings = [t for lvl, t in r.state.messages if lvl == "warning"]
    assert warnings[0] == "PSM1: servo_cp, arm not ready"
    assert r.state.dropped == 2


def test_trajectory_ratio_scales_the_move_and_refuses_out_of_range(rig):
    goal = rig.psm.setpoint_js()[0][:6] + [0.3, 0, 0, 0, 0, 0]
    rig.do("move_jp", lambda: rig.psm.move_jp(goal), moving=True)
    fast = rig.until_idle()
    rig.psm.set_trajectory_ratio(0.25)
    rig.do("move_jp", lambda: rig.psm.move_jp(goal - [0.3, 0, 0, 0, 0, 0]), moving=True)
    slow = rig.until_idle()
    assert slow == pytest.approx(4.0 * fast, rel=0.05)  # the velocity-limited profile: 1/ratio
    rig.psm.set_trajectory_ratio(1.5)
    assert rig.psm.ratio == 0.25
    assert rig.psm.messages[-1] == ("warning", "PSM1: trajectory_j_set_ratio, ratio must be within ]0;1], "
                                               "received 1.5")
