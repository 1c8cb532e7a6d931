"""The real ROS 2 arm driver (RosArm) against `rig sim` in another process, over loopback.

One `rig sim --sim-time` serves the module (from the built-in rig: PSM1 and PSM2 with the
spring between them, seed 3, every stream at 1 kHz), on a ROS domain claimed for the module
(tests/ros_domains.py) with localhost discovery. This process follows its clock in
lockstep, as a procedure does (tests/sim_follower.py, docs/simulated-time.md): every wait,
timeout and stream age of the driver is on the world's time, and a stream of commands is
held to its rate of the world's time. So every figure here is the driver's and the
simulator's, not the machine's: a loaded machine runs the world slower, and this process
with it. Wall-clock limits left are guards against a hang only.

One test is about the wall clock on purpose: the driver's own watchdog against a console
that dies (a real dVRK keeps real time and publishes no /clock). It gets a `rig sim` of
its own on the wall clock and kills it, so the others never depend on running before it.
"""

from __future__ import annotations

import signal
import threading
import time

import numpy as np
import pytest

import rclpy  # noqa: E402  (a declared dependency: a broken install fails here)
from rclpy.context import Context  # noqa: E402

from drivers.common import ros_exit  # noqa: E402
from drivers.common.time_base import WallTime  # noqa: E402
from drivers.arm.crtk import StaleStream  # noqa: E402
from drivers.arm.dvrk_arm import RosArm  # noqa: E402
from drivers.interfaces import Arm  # noqa: E402
from rig.model import psm_kinematics as K  # noqa: E402
from tests.hil.harness import ServedRig  # noqa: E402
from tests.ros_domains import ros_environment  # noqa: E402
from tests.sim_follower import SimFollower  # noqa: E402

pytestmark = pytest.mark.ros

#: rig sim on the built-in rig (an empty rig.toml), seed 3, every arm stream each 1 ms
SIM_ARGS = ("--seed", "3", "--ros-period", "0.001")
#: s of wall time, guards against a hang only (no figure rests on them)
HANG = 120.0


def _said(served: ServedRig) -> str:
    """rig sim's last words (its stderr), for a failure's message."""
    return "".join(served.sim_err)[-2000:]


@pytest.fixture(scope="module")
def rig_sim(tmp_path_factory):
    """rig sim --sim-time, and this process on its clock: PSM1 and PSM2 as RosArms, ENABLED and homed."""
    with ServedRig(tmp_path_factory.mktemp("arm-ros"), toml="", sim_args=SIM_ARGS, sim_time=True) as served, \
            ros_environment(served.domain):
        follower = SimFollower("rig_test")
        try:
            # a stale limit of the world's time: 0.5 s is 500 of its periods
            arms = {n: follower.arm(f"/{n}", watchdog=0.5) for n in ("PSM1", "PSM2")}
            follower.start()
            for arm in arms.values():
                assert arm.wait_for_data(30.0), f"no measured_js on {arm.topic['measured_js']}: {_said(served)}"
                assert arm.wait_for_subscribers(HANG), _said(served)
            for arm in arms.values():  # rig sim's arms start DISABLED, as a dVRK's; 30 s of the world's time
                assert arm.ready(timeout=30.0).ready, _said(served)
            yield {"served": served, "follower": follower, "arms": arms, "lines": served.sim_lines}
        finally:
            follower.close()


def test_startup_prints_loadcell_pty_and_ready(rig_sim):
    lines = rig_sim["lines"]
    pty = [ln for ln in lines if ln.startswith("loadcell: ")]
    assert len(pty) == 1 and pty[0].split(": ", 1)[1].startswith("/dev/pts/")
    assert lines.index(pty[0]) < lines.index("ready")
    assert isinstance(rig_sim["arms"]["PSM1"], Arm)


def test_measured_js_streams_every_rig_period_and_cp_matches_kinematics(rig_sim):
    arm, follower = rig_sim["arms"]["PSM1"], rig_sim["follower"]
    n0 = arm.received
    arm.drain_js()
    stamps: list[float] = []
    # 300 samples: the arm's own log of every measured_js (reliable, in order)
    assert follower.wait_for(lambda: stamps.extend(js.t for js in arm.drain_js()) or len(stamps) >= 300, 30.0), \
        f"{len(stamps)} measured_js in 30 s of the world's time"
    assert arm.received > n0
    # measured_js is published on every rig period (1 ms) and stamped with the world's
    # time, so two messages in a row are 1 ms apart; a stream at the 100 Hz of measured_cp
    # would be 10 ms apart
    gaps = np.round(np.diff(stamps) * 1e9).astype(np.int64)
    assert abs(gaps[gaps > 0].min() - 1_000_000) <= 1_000, f"shortest gap {gaps[gaps > 0].min()} ns"
    js = arm.measured_js()
    assert js.name[:3] == ("outer_yaw", "outer_pitch", "outer_insertion")
    # Stamps on the world's clock, the one /clock carries: measured_js() returns nothing
    # older than the watchdog (0.5 s of that time). Stamps from the epoch or the monotonic
    # clock would be off by decades. (A console on the wall clock stamps from the epoch:
    # the watchdog test's rig sim.)
    assert abs(follower.now() - js.t) <= arm.watchdog, (follower.now(), js.t)
    cp = arm.measured_cp()
    # the dVRK's tool tip (the large needle driver's, wrist straight as the driver holds it)
    from rig.model.psm_arm_kinematics import RIG_TIP_TO_TOOL_TIP
    T = K.tip_pose_rcm(arm.measured_js().position) @ RIG_TIP_TO_TOOL_TIP
    assert np.allclose(cp.position, T[:3, 3], atol=2e-3)  # pose vs newest joints
    assert np.allclose(cp.rotation, T[:3, :3], atol=2e-2)
    assert arm.local_measured_cp().frame == cp.frame
    assert np.all(np.isfinite(arm.body_measured_cf().force))


def test_drain_js_hands_over_every_sample_since_the_last_drain(rig_sim):
    """A loop held up for 0.2 s still gets every measured_js of that time, once, in order."""
    arm = rig_sim["arms"]["PSM1"]
    arm.drain_js()
    n0 = arm.received
    time.sleep(0.2)  # the loop that could not look (the world runs on meanwhile, free)
    got = arm.drain_js()
    n1 = arm.received
    assert len(got) >= n1 - n0 > 0  # whatever arrived since, and nothing twice
    t = [js.t for js in got]
    assert all(b > a for a, b in zip(t, t[1:]))
    assert arm.drain_js() == [] or arm.received > n1


def test_servo_jp_moves_toward_the_command(rig_sim):
    arm, follower = rig_sim["arms"]["PSM1"], rig_sim["follower"]
    assert arm.move_jp(np.array([0.0, 0.0, 0.12]), wait=True, timeout=8.0)
    q0 = arm.measured_js().position
    target = q0 + np.array([0.08, -0.05, 0.01])

    def near() -> bool:
        return bool(np.all(np.abs(arm.measured_js().position - target) < np.abs(target - q0) * 0.2))

    # the dVRK expects a stream of servo commands, as a procedure sends them: 50 Hz of the
    # world's time, for well under the 10 s of it allowed
    follower.stream(50.0, lambda: arm.servo_jp(target), [arm], seconds=10.0, until=near)
    q = arm.measured_js().position
    assert np.all(np.abs(q - target) < np.abs(target - q0) * 0.2), (q0, target, q)
    assert np.allclose(arm.setpoint_js().position, target, atol=1e-9)


def test_servo_jf_moves_the_joint_the_right_way(rig_sim):
    arm, follower = rig_sim["arms"]["PSM2"], rig_sim["follower"]
    js = arm.measured_js()
    hold_effort = js.effort.copy()  # what the PID spends holding: gravity and the object
    q0 = js.position.copy()
    for sign in (+1.0, -1.0):
        arm.servo_jf(hold_effort + np.array([sign * 0.8, 0.0, 0.0]))
        # 0.8 N m on joint 1 moves it 0.01 rad in well under 0.15 s of the world's time (1 s allowed)
        follower.wait_for(lambda: sign * (arm.measured_js().position[0] - q0[0]) > 0.01, 1.0)
        q1 = arm.measured_js().position
        assert sign * (q1[0] - q0[0]) > 0.01, f"effort sign {sign:+.0f}: q1 moved {q1[0] - q0[0]:+.4f} rad"
        arm.move_jp(q0, wait=True, timeout=5.0)
    arm.hold()


def test_move_jp_waits_until_arrived_and_times_out(rig_sim):
    arm, follower = rig_sim["arms"]["PSM1"], rig_sim["follower"]
    # Goals the arm can reach while the spring object pulls on the tip (a pitch of
    # 0.15 rad saturates joint 2 against the object at the 5 N m drive limit).
    goal = np.array([-0.15, -0.05, 0.125])
    t0 = follower.now()
    assert arm.move_jp(goal, wait=True, timeout=8.0)
    elapsed = follower.now() - t0
    assert (arm.move_wait, arm.move_end) == ("busy", "arrived")  # rig sim publishes operating_state: the wait is on is_busy
    assert not arm.operating_state().is_busy
    q = arm.measured_js().position
    assert np.all(np.abs(q - goal) <= 1.5 * np.array([2e-3, 2e-3, 1e-3]))
    # 0.15 rad at half the 2 rad/s limit cannot take less than ~0.3 s with a smooth profile
    assert elapsed > 0.25
    t0 = follower.now()
    assert arm.move_jp(np.array([0.08, -0.05, 0.13]), wait=True, timeout=0.1) is False
    # Never before the timeout, on the clock the timeout is on (that it returns at all is
    # the mechanism's other half); the world's time comes in whole ns
    assert follower.now() - t0 >= 0.1 - 1e-9 and arm.move_end == "timeout"
    assert arm.move_jp(np.array([0.0, 0.0, 0.12]), wait=True, timeout=8.0)


def test_servo_ci_is_a_spring_the_arm_closes_itself(rig_sim):
    """servo_ci: the impedance runs in the arm's servo loop; moving its goal 5 mm moves the
    tool tip's rest 5 mm (the rest sits off the goal by the arm's residual over the
    stiffness: friction offsets that the gravity compensation does not know)."""
    arm, follower = rig_sim["arms"]["PSM2"], rig_sim["follower"]
    assert arm.move_jp(np.array([0.0, 0.0, 0.12]), wait=True, timeout=10.0)
    arm.use_gravity_compensation(True)
    follower.sleep(0.3)
    start = arm.measured_cp()
    rest = []
    for dx in (0.0, 0.005):
        # streamed, as servo commands are, at 50 Hz of the world's time; the arm settles in
        # well under a second of it: 1.5 s
        follower.stream(50.0, lambda dx=dx: arm.servo_ci(start.position + [dx, 0.0, 0.0], start.rotation,
                                                         stiffness=1000.0, damping=25.0, torque_stiffness=0.05,
                                                         torque_damping=0.001), [arm], seconds=1.5)
        rest.append(arm.measured_cp().position)
    assert np.linalg.norm(rest[0] - start.position) < 0.006
    # within the arm's friction band: Coulomb friction of about 0.2 N m on joints 1-2 at
    # 0.1 m from the RCM is 2 N at the tip, 2 mm on a 1000 N/m spring, either way
    moved = rest[1] - rest[0]
    assert abs(moved[0] - 0.005) < 3e-3 and np.all(np.abs(moved[1:]) < 1e-3), moved
    # back under position control first, then the compensation off
    assert arm.move_jp(np.array([0.0, 0.0, 0.12]), wait=True, timeout=30.0)
    arm.use_gravity_compensation(False)


# -- a console on the wall clock, killed ---------------------------------------------------
class _Looks(WallTime):
    """The wall clock, noting every look of an arm's watchdog thread: the time it judged the
    stream's age at (its `now()` just before it asks `stalled()`; both are called once a
    look, from that thread only, while the stream has not gone stale)."""

    def __init__(self):
        self.looks: list[float] = []
        self._now = threading.local()

    def now(self) -> float:
        t = time.monotonic()
        self._now.t = t
        return t

    def last_now(self) -> float:
        """The time this thread's last now() returned."""
        return self._now.t

    def stalled(self):
        self.looks.append(self._now.t)
        return None


@pytest.fixture
def wall_sim(tmp_path):
    """rig sim on the wall clock, as a real console (the test kills it)."""
    with ServedRig(tmp_path, toml="", sim_args=SIM_ARGS) as served, ros_environment(served.domain):
        yield served


def test_watchdog_fires_once_the_stream_is_silent_for_its_interval(wall_sim):
    """A console on the wall clock stamps its streams from the epoch; killed, its stream
    goes stale for the driver after the watchdog's interval (50 ms) of silence, never
    before: measured_js() raises, and the watchdog thread fires its callback at its first
    look past the interval."""
    ctx, node = Context(), None
    looks = _Looks()
    events: list[tuple[float, StaleStream]] = []
    try:
        rclpy.init(context=ctx)
        node = rclpy.create_node("rig_test_watch", context=ctx)
        arm = RosArm(node, "/PSM1", on_stale=lambda e: events.append((time.monotonic(), e)), time_base=looks)
        try:
            assert arm.watchdog == 0.05 and arm.wait_for_data(HANG), _said(wall_sim)
            guard = time.monotonic() + HANG
            while len(looks.looks) < 20 or arm.stream_age() > 0.01:  # its watchdog at work, the stream fresh
                assert time.monotonic() < guard, _said(wall_sim)
                time.sleep(0.002)
            # Stamps from the epoch, as a console's: never ahead of this host's clock (by more
            # than a period), and behind it by rig sim's lag, the delivery and the read, which
            # a loaded machine makes what it makes. A stamp from zero, or from the monotonic
            # clock (the time since boot), is behind by decades.
            js = arm.measured_js()
            assert -0.01 < time.time() - js.t < 3600.0, (time.time(), js.t)
            wall_sim.kill(signal.SIGKILL)
            # measured_js() returns data only while it is at most the watchdog interval old,
            # and raises once it is older. Each return is checked against the age read just
            # before the call (when no message came in between), so the check holds however
            # late this loop runs.
            while True:
                n, age = arm.received, arm.stream_age()
                try:
                    arm.measured_js()
                except StaleStream as err:
                    assert "/PSM1/measured_js" in str(err) and err.age > arm.watchdog
                    break
                assert arm.received != n or age <= arm.watchdog, f"measured_js returned data {age * 1e3:.0f} ms old"
                assert time.monotonic() < guard, "measured_js never went stale"
                time.sleep(0.001)
            # The watchdog thread looks every watchdog / 5 and fires at its first look past
            # the interval after the last message (a message still on its way when rig sim
            # died counts as the last). It fires from its own thread, so it is waited for.
            while True:
                n = arm.received
                age = arm.stream_age()
                last_rx = looks.last_now() - age  # the last message's arrival, on this clock
                fired = [(t, e) for t, e in events if t >= last_rx]
                if fired and arm.received == n:
                    break
                assert time.monotonic() < guard, "the stale callback did not fire"
                time.sleep(0.002)
            t_fired, err = fired[0]
            assert err.age > arm.watchdog and t_fired - last_rx > arm.watchdog, "fired before the interval"
            # ... at its first look past the interval: every look since the last message saw it
            # younger than the interval, but the one that fired, which saw the age it reports.
            # (A loaded machine delays the looks, and with them the callback; it cannot make
            # a look past the interval pass without firing.)
            since = [t - last_rx for t in looks.looks if t >= last_rx]
            assert since and all(a <= arm.watchdog for a in since[:-1]), since
            assert since[-1] > arm.watchdog and since[-1] == pytest.approx(err.age, abs=1e-9), (since[-1], err.age)
            assert t_fired >= last_rx + since[-1]
            # it looks several times an interval (watchdog / 5 apart): load lengthens a gap,
            # it never shortens one
            gaps = np.diff(looks.looks)
            assert gaps.size >= 19 and gaps.min() < arm.watchdog / 2, gaps.min()
            with pytest.raises(StaleStream):
                arm.move_jp(np.zeros(3), wait=True, timeout=1.0)
        finally:
            arm.close()
    finally:
        # parked, not destroyed: rig sim was killed mid-stream, after which deleting the
        # participant crashed this process (drivers/common/ros_exit.py)
        ros_exit.teardown((node,) if node is not None else (), ctx)
