"""The dVRK's operating state as rig sim serves it (drivers.arm.fake_arm_state), in-process on the
simulated clock: the transitions, the dropped commands and their throttled warning, busy,
the faults. Over the wire: tests/hil/test_operating_state.py."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.arm.sim import SimArm
from drivers.arm.fake_arm_state import HOMING, NOT_READY_PERIOD, POWERING, FakeArmState
from rig import config
from rig.devices.clock import SimClock
from rig.sim.world import world_from_config


class _Rig:
    def __init__(self):
        self.world = world_from_config(config.load(None), arms=["PSM1"], with_object=False)
        self.clock = SimClock(self.world)
        self.arm = SimArm(self.world, "PSM1", self.clock)
        self.state = FakeArmState(self.arm)

    @property
    def t(self) -> float:
        return self.world.t

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / self.world.dt))):
            self.clock.tick()
            self.state.step(self.world.t)

    def q(self) -> np.ndarray:
        return self.world.measured_js("PSM1")[0]

    def ready(self) -> None:
        self.state.command("home", self.t)  # from DISABLED: powers, then homes
        self.run(POWERING + HOMING + 0.5)
        assert self.state.ready and not self.state.is_busy


@pytest.fixture
def rig():
    return _Rig()


def test_starts_disabled_and_drops_motion_with_the_dvrks_throttled_warning(rig):
    s = rig.state
    assert (s.state, s.is_homed, s.is_busy) == ("DISABLED", False, False)
    q0 = rig.q().copy()
    for k in range(50):  # 50 servo_jp over 5 s of rig time
        assert s.servo_jp(q0 + [0.2, 0.1, 0.02], None, rig.t) is False
        rig.run(0.1)
    assert s.move_jp(q0 + [0.2, 0.0, 0.0], rig.t) is False
    assert s.dropped == 51
    warnings = [text for level, text in s.messages if level == "warning"]
    # at most one per NOT_READY_PERIOD; from the second on, the count of those dropped before
    assert len(warnings) == int(5.0 / NOT_READY_PERIOD) + 1
    assert warnings[0] == "PSM1: servo_jp, arm not ready"
    assert warnings[1].startswith("PSM1: servo_jp, arm not ready (") and warnings[1].endswith(" errors)")
    assert np.all(np.abs(rig.q() - q0) < 1e-3)  # nothing moved it


def test_enable_then_home_takes_its_time_busy_meanwhile(rig):
    s = rig.state
    s.command("enable", rig.t)
    assert (s.state, s.is_busy) == ("DISABLED", True)  # powering
    rig.run(POWERING + 0.01)
    assert (s.state, s.is_homed, s.is_busy) == ("ENABLED", False, False)
    assert s.servo_jp(rig.q(), None, rig.t) is False  # enabled, not homed: still dropped
    t0 = rig.t
    s.command("home", rig.t)
    busy_until = None
    while s.is_busy or busy_until is None:
        rig.run(0.01)
        if not s.is_busy and busy_until is None:
            busy_until = rig.t
        assert rig.t - t0 < 10.0
    assert s.is_homed and busy_until - t0 >= HOMING
    assert np.allclose(rig.q(), rig.arm.home_position, atol=2e-3)
    s.command("home", rig.t)  # homed already: nothing moves, no busy
    assert not s.is_busy


def test_busy_during_move_jp_until_its_trajectory_ends(rig):
    """The dVRK's busy ends when the trajectory's set-point reached the goal (Reflexxes'
    final state); the joints settle on it under the PID afterwards."""
    rig.ready()
    s = rig.state
    goal = rig.arm.home_position + np.array([0.2, -0.1, 0.02])
    assert s.move_jp(goal, rig.t) and s.is_busy
    t0 = rig.t
    while s.is_busy:
        assert rig.arm.is_moving()
        rig.run(0.001)
    assert not rig.arm.is_moving()
    assert rig.t - t0 > 0.2  # 0.2 rad at half of 2 rad/s, on a smooth profile
    np.testing.assert_allclose(rig.world.setpoint_js("PSM1")[0], goal, atol=1e-12)
    rig.run(1.0)
    assert rig.arm.arrived()
    assert np.all(np.abs(rig.q() - goal) <= [2e-3, 2e-3, 1e-3])
    assert s.servo_jp(goal, None, rig.t) and not s.is_busy


def test_a_joint_past_its_limit_faults_and_only_disable_leads_out(rig):
    rig.ready()
    s = rig.state
    s.push_past_limit(2)
    rig.run(0.002)
    assert (s.state, s.is_busy) == ("FAULT", False)
    level, text = s.messages[-1]
    assert level == "error" and text.startswith("PSM1: joint 2 at 0.9") and "past its limit [-0.93, 0.93] rad" in text
    for command in ("enable", "home", "resume"):
        s.command(command, rig.t)
        assert s.messages[-1] == ("warning", f'PSM1: command "{command}" is not supported in state "FAULT"')
        assert s.state == "FAULT"
    assert s.servo_jp(rig.q(), None, rig.t) is False
    s.command("disable", rig.t)
    assert s.state == "DISABLED" and s.is_homed  # disabling keeps the homing, as on the dVRK
    s.command("enable", rig.t)
    rig.run(POWERING + 0.01)
    assert s.state == "FAULT"  # still past its limit: it faults again once powered


def test_a_power_loss_faults_a_powered_arm_where_it_stands(rig):
    rig.ready()
    s = rig.state
    q = rig.q().copy()
    s.lose_power()
    assert (s.state, s.is_busy) == ("FAULT", False)
    assert s.messages[-1] == ("error", "PSM1: detected power loss (actuators)")
    rig.run(0.5)
    np.testing.assert_allclose(rig.q(), q, atol=1e-4)  # it stays where it was
    assert s.servo_jp(q + 0.1, None, rig.t) is False
    s.command("disable", rig.t)
    n = len(s.messages)
    s.lose_power()  # a disabled arm has no power to lose
    assert s.state == "DISABLED" and len(s.messages) == n


def test_the_servo_watchdog_faults_an_arm_whose_servo_commands_stop(rig):
    rig.ready()
    s = rig.state
    s.servo_watchdog = 0.05
    q = rig.q().copy()
    for _ in range(100):  # a 1 kHz servo stream keeps it fed
        s.servo_jp(q, None, rig.t)
        rig.run(0.001)
    assert s.state == "ENABLED"
    rig.run(0.06)
    assert s.state == "FAULT" and "watchdog: no servo command for" in s.messages[-1][1]
    s.command("disable", rig.t)
    s.command("enable", rig.t)
    rig.run(POWERING + 0.01)
    assert s.ready  # a move_jp is not servo mode: no watchdog after a move
    assert s.move_jp(q, rig.t)
    rig.run(0.5)
    assert s.state == "ENABLED"


def test_pause_resume_and_unhome(rig):
    rig.ready()
    s = rig.state
    s.command("pause", rig.t)
    assert s.state == "PAUSED" and s.servo_jp(rig.q(), None, rig.t) is False
    s.command("resume", rig.t)
    assert s.ready
    s.command("unhome", rig.t)
    assert s.state == "ENABLED" and not s.is_homed and not s.ready
