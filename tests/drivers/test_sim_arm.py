"""SimArm (the in-process dVRK arm fake) on the simulated world and its clock."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.interfaces import Arm
from drivers.arm.sim import JointTrajectory, SimArm
from rig import config
from rig.devices.clock import SimClock, WallClock
from rig.model import psm_kinematics as K
from rig.sim.world import world_from_config


@pytest.fixture
def rig():
    """One arm, no object (so commands are not fought by the spring), settled 0.3 s."""
    cfg = config.parse({}, "test")
    world = world_from_config(cfg, arms=["PSM1"], with_object=False, seed=5)
    clock = SimClock(world)
    arm = SimArm(world, "PSM1", clock)
    clock.sleep(0.3)
    return world, clock, arm


def test_is_an_arm(rig):
    assert isinstance(rig[2], Arm)


def test_servo_jp_reaches_the_set_point(rig):
    world, clock, arm = rig
    target = np.array([0.2, -0.15, 0.15])
    arm.servo_jp(target)
    assert np.allclose(arm.setpoint_js().position, target)
    clock.sleep(1.5)
    js = arm.measured_js()
    assert np.all(np.abs(js.position - target) < [3e-3, 3e-3, 1.5e-3]), js.position
    assert js.t == pytest.approx(clock.now())


def test_servo_jf_moves_each_joint_the_way_it_is_pushed(rig):
    world, clock, arm = rig
    hold = arm.measured_js().effort  # the PID's effort at rest balances gravity
    for j, push in ((0, 0.6), (0, -0.6), (2, 3.0), (2, -3.0)):
        arm.move_jp([0.0, 0.0, 0.12], timeout=5.0)
        q0 = arm.measured_js().position
        tau = hold.copy()
        tau[j] += push
        arm.servo_jf(tau)
        assert world.mode("PSM1") == "effort"
        clock.sleep(0.1)
        dq = arm.measured_js().position - q0
        assert np.sign(dq[j]) == np.sign(push) and abs(dq[j]) > 1e-3, (j, push, dq)


def test_measured_cp_is_the_kinematics_of_the_measured_joints(rig):
    """The dVRK's measured_cp, as RosArm reads it from a console: the whole PSM's tool tip
    (the large needle driver, wrist straight) in the arm's base frame (the RCM frame)."""
    from rig.model.psm_arm_kinematics import PSMKinematics

    world, clock, arm = rig
    arm.move_jp([0.3, -0.2, 0.16], timeout=5.0)
    q = arm.measured_js().position
    cp = arm.measured_cp()
    T = PSMKinematics().forward(np.concatenate([q, np.zeros(3)]))
    assert np.allclose(cp.position, T[:3, 3], atol=1e-9) and np.allclose(cp.rotation, T[:3, :3], atol=1e-9)
    assert cp.frame == "PSM1_base"
    # 9.1 mm beyond the shaft end (what the world's kinematics calls the tip), along the shaft
    shaft_end = K.tip_in_rcm(q)
    assert np.linalg.norm(cp.position - shaft_end) == pytest.approx(0.0091, abs=1e-4)
    # the world-frame variant agrees with the world's true tool within encoder quantisation
    Tw = world.arms["PSM1"].rcm_world @ T
    assert np.allclose(arm.measured_cp_world().position, Tw[:3, 3], atol=1e-9)
    assert np.linalg.norm(arm.measured_cp_world().position - world.tip_world("PSM1")) == pytest.approx(0.0091, abs=2e-4)
    assert np.allclose(arm.local_measured_cp().position, cp.position)


def test_move_jp_respects_velocity_limits_and_arrives(rig):
    world, clock, arm = rig
    goal = np.array([1.0, -0.6, 0.2])
    peak = np.zeros(3)
    t0 = clock.now()
    arm.move_jp(goal, wait=False)
    while arm.is_moving():
        clock.tick()
        sp = world.setpoint_js("PSM1")[1]
        peak = np.maximum(peak, np.abs(sp))
        peak = np.maximum(peak, np.abs(world.true_state("PSM1")[1]))
    assert np.all(peak <= K.DQ_MAX), peak
    assert np.all(peak <= 0.5 * K.DQ_MAX * 1.05)  # the default ratio, with PID overshoot
    assert peak[0] > 0.4 * K.DQ_MAX[0]  # and it is not crawling: joint 1 leads this move
    assert arm.wait_move(timeout=5.0)
    assert np.all(np.abs(arm.measured_js().position - goal) <= [2e-3, 2e-3, 1e-3])
    assert clock.now() - t0 > 1.875 * 1.0 / 1.0  # 1 rad at 1 rad/s peak: at least 1.875 s


def test_move_jp_times_out_on_clock_time(rig):
    world, clock, arm = rig
    t0 = clock.now()
    assert arm.move_jp([1.0, 0.5, 0.2], wait=True, timeout=0.2) is False
    assert clock.now() - t0 == pytest.approx(0.2, abs=2 * world.dt)
    # the move goes on, as on the dVRK
    assert arm.wait_move(timeout=10.0)


def test_move_jp_refuses_goals_outside_the_joint_limits(rig):
    arm = rig[2]
    with pytest.raises(ValueError, match="joint 3 position"):
        arm.move_jp([0.0, 0.0, 0.3])
    with pytest.raises(ValueError, match="non-finite"):
        arm.servo_jp([0.0, float("nan"), 0.1])


def test_hold_and_power(rig):
    world, clock, arm = rig
    arm.power_off()
    assert world.mode("PSM1") == "off"
    clock.sleep(0.05)
    arm.power_on()
    q = arm.measured_js().position
    clock.sleep(0.5)
    assert np.all(np.abs(arm.measured_js().position - q) < 0.02)
    assert arm.home(timeout=5.0)
    assert np.all(np.abs(arm.measured_js().position - [0.0, 0.0, 0.12]) <= [2e-3, 2e-3, 1e-3])


def test_trajectory_profile_is_smooth_and_limited():
    tr = JointTrajectory.plan(np.zeros(3), np.array([0.5, -0.2, 0.05]), 1.0,
                              np.array([1.0, 1.0, 0.2]), np.array([6.0, 6.0, 1.2]))
    ts = np.linspace(1.0, tr.end(), 2001)
    q = np.array([tr.sample(t)[0] for t in ts])
    dq = np.array([tr.sample(t)[1] for t in ts])
    assert np.allclose(q[0], 0) and np.allclose(q[-1], [0.5, -0.2, 0.05])
    assert np.all(np.abs(dq).max(axis=0) <= [1.0, 1.0, 0.2 + 1e-12])
    assert np.allclose(np.gradient(q, ts, axis=0), dq, atol=2e-3)


class FakeTime:
    """Stands in for the `time` module inside rig.devices.clock: every sleep() overshoots by
    `slack` s, as a real timer does, and nothing else takes any time."""

    def __init__(self, slack: float) -> None:
        self.t, self.slack = 100.0, slack

    def perf_counter(self) -> float:
        return self.t

    def time(self) -> float:
        return 1.7e9 + self.t

    def sleep(self, duration: float) -> None:
        assert duration >= 0
        self.t += duration + self.slack


def test_wall_clock_boundaries_come_from_the_start_not_from_the_last_wake_up(monkeypatch):
    import rig.devices.clock

    fake = FakeTime(slack=0.3e-3)
    monkeypatch.setattr(rig.devices.clock, "time", fake)
    clock = WallClock(500.0)
    start = fake.t
    for _ in range(100):
        clock.tick()
    # On boundary 100, late only by the last sleep's slack; chaining periods from each
    # wake-up would be late by 100 slacks (30 ms).
    assert fake.t - start == pytest.approx(100 * 0.002 + 0.3e-3, abs=1e-9)
    assert clock.overruns == 0 and clock.skipped == 0
    fake.t += 0.010  # the loop is busy for 10 ms: boundaries 101-105 pass
    clock.tick()  # an overrun (taking boundary 105) returns at once; 101-104 are skipped
    assert fake.t - start == pytest.approx(0.2003 + 0.010, abs=1e-9)
    assert clock.overruns == 1 and clock.skipped == 4
    clock.tick()  # the next boundary, 106, not a burst replaying the missed ones
    assert fake.t - start == pytest.approx(106 * 0.002 + 0.3e-3, abs=1e-9)
    assert clock.overruns == 1 and clock.skipped == 4


def test_wall_clock_ticks_on_the_real_clock():
    # The same mechanism on the real clock. No tick returns before its boundary, and the
    # loop ends on boundary 100 + skipped (a tick that finds itself a whole period late
    # skips the boundaries it missed instead of replaying them). The upper bound adds one
    # wake-up latency: on a loaded machine the last sleep may return late by a scheduler
    # time slice or a few (tens of ms on two busy cores); 0.1 s is 50 periods, and delays
    # of earlier ticks do not add up (that is the mechanism under test, without slack
    # from the scheduler in the test above).
    before = time.perf_counter()
    clock = WallClock(500.0)
    made = time.perf_counter()
    seen = []
    clock.add_listener(seen.append)
    for _ in range(100):
        clock.tick()
    end = time.perf_counter()
    assert len(seen) == 100 and all(b > a for a, b in zip(seen, seen[1:]))
    boundaries = (100 + clock.skipped) * clock.period
    assert end - before >= boundaries
    assert end - made < boundaries + 0.1
    overruns, skipped = clock.overruns, clock.skipped
    time.sleep(0.01)  # miss at least 5 boundaries: the next tick is late by >= 8 ms
    clock.tick()
    assert clock.overruns == overruns + 1 and clock.skipped >= skipped + 4
