"""The dVRK's operating state over the wire: `rig sim` serves it, `RosArm` and the procedures obey it.

One `rig sim` serves the module from a lab's rig.toml. This process is a client of its
own (a RosSession with a RosArm on PSM2, the operator channel, and subscriptions that
record PSM2's operating_state and warnings), and the last tests run procedures on PSM1 in
other processes. The cases: a never-enabled arm drops commands with the dVRK's warning
and does not move; enable and home through RosArm; move_jp waits on is_busy; the servo
watchdog faults an arm whose servo commands stop, and the fault is cleared by a disable;
a FAULT mid-run (PSM1's joint 1 pushed past its limit) aborts the procedure with one line,
the arm held, the recording closed with the reason; the next procedure on that arm stops
when connecting, the FAULT left for a person to clear.

All on simulated time: `rig sim --sim-time`, the procedures with `[ros] use_sim_time`, and
this process following the world's clock in lockstep (tests/sim_follower.py). A stream of
servo commands is held to its rate of the world's time, so the servo watchdog (on the
world's time in rig sim) and the warnings' throttle see what the test sends, however busy
the machine is; every duration asserted is the world's.

Each test makes the state it needs (tests run in any order, alone or in any subset): one
that needs an arm as a console leaves it at power-up (DISABLED, never homed; PSM1 not in
FAULT) gets a fresh rig sim when an earlier test changed it; one that needs PSM2 enabled
enables it; the one that needs PSM1 in FAULT faults it mid-run first if it is not. In
the file's order nothing is restarted.

A domain claimed for the module (tests/ros_domains.py), localhost discovery.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig  # noqa: E402
from tests.ros_domains import ros_environment  # noqa: E402
from tests.sim_follower import SimFollower  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]

#: s of the world's time a never-enabled arm is streamed servo_jp
STREAM = 3.0
#: s of wall time, guards against a hang only (no figure rests on them)
HANG = 120.0


class _Client:
    """This process's side, on the world's clock: a RosArm on PSM2 (never enabled until the
    second test), the operator channel, and PSM2's operating_state and warning messages as
    they arrive (with the monotonic time they came at: their order)."""

    def __init__(self):
        from std_msgs.msg import String

        from crtk_msgs.msg import OperatingState

        self.follower = SimFollower("state_test")
        self.arm = self.follower.arm("/PSM2", watchdog=1.0)
        self.operator = self.follower.operator(timeout=20.0)
        self.states: list[tuple[float, str, bool, bool]] = []  # (monotonic, state, homed, busy)
        self.warnings: list[tuple[float, str]] = []
        # on the arm's control node (events as the arm hears them, on the same executor)
        control = self.follower.session.control
        control.create_subscription(OperatingState, "/PSM2/operating_state",
                                    lambda m: self.states.append((time.monotonic(), m.state, m.is_homed, m.is_busy)),
                                    100)
        control.create_subscription(String, "/PSM2/warning",
                                    lambda m: self.warnings.append((time.monotonic(), m.data)), 100)
        self.follower.start()

    def stream(self, rate: float, command, seconds: float, until=None) -> int:
        """`command()` at `rate` Hz of the world's time (SimFollower.stream, on PSM2's samples)."""
        return self.follower.stream(rate, command, [self.arm], seconds, until)

    def close(self) -> None:
        self.follower.close()


def _settle(c: _Client, timeout: float = 20.0) -> None:
    """Wait until the arm's joints stay within 0.2 mrad (0.2 mm) over 0.5 s of the world's
    time: freed of the object's pull, its PID lets go of the integral that held against it."""
    arm = c.arm
    deadline = c.follower.now() + timeout
    q = arm.measured_js().position.copy()
    while True:
        c.follower.sleep(0.5)
        q1 = arm.measured_js().position.copy()
        if np.all(np.abs(q1 - q) < 2e-4):
            return
        assert c.follower.now() < deadline, f"{arm.name} did not settle: {q} -> {q1}"
        q = q1


def _connect(rig: ServedRig) -> None:
    """This process's client on `rig` (rig.client), the object detached and PSM2 settled;
    rig.changed: what tests did to the arms since this rig sim started."""
    client = _Client()
    rig.client, rig.changed = client, set()
    assert client.arm.wait_for_data(30.0) and client.arm.wait_for_state(30.0)
    assert client.arm.wait_for_subscribers(HANG)
    client.operator.detach_object()  # the arms move free of the spring between them
    _settle(client)


def _fresh(rig: ServedRig, unless_unchanged: tuple[str, ...]) -> ServedRig:
    """`rig` as at power-up for what a test needs: a fresh rig sim and client if any of
    `unless_unchanged` ("PSM2 enabled", "PSM1 faulted") happened to this one."""
    if rig.changed & set(unless_unchanged):
        rig.client.close()
        rig.restart()
        _connect(rig)
    return rig


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    with ServedRig(tmp_path_factory.mktemp("states"), sim_time=True) as rig, ros_environment(rig.domain):
        _connect(rig)
        try:
            yield rig
        finally:
            rig.client.close()


def _ready_psm2(served: ServedRig):
    """PSM2 ENABLED and homed (enabled and homed through RosArm if it is not)."""
    served.changed.add("PSM2 enabled")
    st = served.client.arm.ready(timeout=30.0)
    assert st.ready, st
    return served.client


def test_a_never_enabled_arm_drops_commands_warns_and_does_not_move(served):
    from drivers.arm.fake_arm_state import NOT_READY_PERIOD

    c = _fresh(served, ("PSM2 enabled",)).client
    arm = c.arm
    st = arm.operating_state()
    assert (st.state, st.is_homed, st.is_busy) == ("DISABLED", False, False)
    q0 = arm.measured_js().position.copy()
    t0 = time.monotonic()
    # a client streaming servo_jp at 50 Hz of the world's time for 3 s of it, without enabling
    sent = c.stream(50.0, lambda: arm.servo_jp(q0 + np.array([0.1, -0.1, 0.01])), seconds=STREAM)
    assert sent == round(50.0 * STREAM)
    c.follower.sleep(0.5)
    q = arm.measured_js().position
    assert np.all(np.abs(q - q0) < 1e-3), (q0, q)  # held where it was: nothing obeyed
    # the dVRK's words, throttled to one per NOT_READY_PERIOD (2 s) of the rig's time, the
    # later ones counting what was dropped since the arm was last ready. The warnings come
    # in order on their topic: one more command, a throttle's period after the stream,
    # gets the last word, and every warning of the stream has come before it.
    c.follower.sleep(NOT_READY_PERIOD)
    arm.servo_jp(q0)
    last = f"PSM2: servo_jp, arm not ready ({sent} errors)"  # every command of the stream dropped
    guard = time.monotonic() + HANG
    while not any(text == last for t, text in c.warnings if t >= t0):
        assert time.monotonic() < guard, [text for t, text in c.warnings if t >= t0]
        time.sleep(0.01)
    said = [text for t, text in c.warnings if t >= t0]
    assert said[-1] == last, said
    said = said[:-1]
    assert said and said[0] == "PSM2: servo_jp, arm not ready", said
    assert len(said) == int(STREAM / NOT_READY_PERIOD) + 1, said  # at its start, and 2 s later
    assert said[1].startswith("PSM2: servo_jp, arm not ready (") and said[1].endswith(" errors)"), said
    # a move_jp is dropped too: its busy flag never rises, and the wait says so once the
    # flag is overdue (not by running out its timeout)
    assert arm.move_jp(q0 + np.array([0.1, 0.0, 0.0]), wait=True, timeout=120.0) is False
    assert (arm.move_wait, arm.move_end) == ("busy", "dropped")
    assert arm.operating_state().state == "DISABLED"
    # and nothing of it reaches the joints
    assert np.all(np.abs(arm.measured_js().position - q0) < 1e-3)


def test_enable_and_home_through_rosarm_within_the_timeout(served):
    from drivers.arm.fake_arm_state import HOMING

    c = _fresh(served, ("PSM2 enabled",)).client
    served.changed.add("PSM2 enabled")
    t0, w0 = time.monotonic(), c.follower.now()
    st = c.arm.ready(timeout=30.0)
    took = c.follower.now() - w0
    assert (st.state, st.is_homed, st.is_busy) == ("ENABLED", True, False)
    guard = time.monotonic() + HANG  # this test's own subscription may take the last event after the arm's
    while ("ENABLED", True, False) not in [(s, h, b) for t, s, h, b in c.states if t >= t0]:
        assert time.monotonic() < guard, c.states
        time.sleep(0.01)
    seen = [(s, h, b) for t, s, h, b in c.states if t >= t0]
    # powering (DISABLED, busy), ENABLED, homing (ENABLED, not homed, busy), homed
    assert ("DISABLED", False, True) in seen and ("ENABLED", False, True) in seen, sorted(set(seen))
    assert seen.index(("ENABLED", False, True)) < seen.index(("ENABLED", True, False))
    assert took >= HOMING  # a homing takes its time, of the world's
    # ENABLED and homed, the arm obeys: a servo_jp moves it (streamed at 100 Hz, within 10 s)
    q0 = c.arm.measured_js().position.copy()
    target = q0 + np.array([0.03, 0.0, 0.0])

    def there() -> bool:
        return abs(c.arm.measured_js().position[0] - target[0]) <= 2e-3

    c.stream(100.0, lambda: c.arm.servo_jp(target), seconds=10.0, until=there)
    assert there(), c.arm.measured_js().position


def test_move_jp_waits_on_is_busy(served):
    c = _ready_psm2(served)
    arm = c.arm
    q0 = arm.measured_js().position.copy()
    goal = q0 + np.array([-0.1, 0.05, 0.0])
    t0, w0 = time.monotonic(), c.follower.now()
    assert arm.move_jp(goal, wait=True, timeout=15.0)
    took = c.follower.now() - w0
    # the arm's own view: the wait ended on is_busy's fall, at the goal
    assert (arm.move_wait, arm.move_end) == ("busy", "arrived")
    assert not arm.operating_state().is_busy
    # 0.1 rad at half of 2 rad/s on a smooth profile takes more than 0.15 s of the world's time
    assert took > 0.15
    assert np.all(np.abs(arm.measured_js().position - goal) <= np.array([2e-3, 2e-3, 1e-3]))
    # this test's own subscription heard it rise, then fall (on the same executor as the
    # arm's, one callback after it: waited for)
    guard = time.monotonic() + HANG

    def rose_and_fell() -> bool:
        busy = [b for t, s, h, b in c.states if t >= t0]
        return True in busy and False in busy[busy.index(True):]

    while not rose_and_fell():
        assert time.monotonic() < guard, [(s, h, b) for t, s, h, b in c.states if t >= t0]
        time.sleep(0.01)


def test_servo_watchdog_faults_an_arm_whose_servo_commands_stop(served):
    from drivers.arm.crtk import ArmFault

    c = _ready_psm2(served)
    arm = c.arm
    q = arm.measured_js().position.copy()
    # out of servo mode first (a move ends it): a watchdog armed in servo mode would judge a
    # servo command of an earlier test
    assert arm.move_jp(q, wait=True, timeout=15.0)
    c.operator.fault("PSM2", "servo_watchdog", timeout=0.2)
    try:
        # a servo stream at 100 Hz of the world's time keeps it fed for 1 s of it
        assert c.stream(100.0, lambda: arm.servo_jp(q), seconds=1.0) == 100
        assert arm.operating_state().state == "ENABLED"
        stopped = c.follower.now()  # then the stream stops
        with pytest.raises(ArmFault) as err:
            while True:
                arm.measured_js()
                assert c.follower.now() - stopped < 10.0, "the arm did not fault"
                c.follower.sleep(0.01)
        line = str(err.value)
        assert "\n" not in line
        assert "/PSM2/operating_state: PSM2 went to FAULT during the run" in line, line
        assert "watchdog: no servo command for" in line, line
        assert arm.operating_state().state == "FAULT"
        # asked, the arm's operating_state service answers the same
        answers = arm.state_answers
        assert arm.confirm_state(5.0).state == "FAULT"
        assert arm.state_answers == answers + 1
        # a FAULT is not cleared behind a person's back: ready() names it
        with pytest.raises(ArmFault, match="PSM2 is FAULT"):
            arm.ready(timeout=5.0)
    finally:
        c.operator.fault("PSM2", "servo_watchdog", timeout=0.0)  # disarmed
    arm.state_command("disable")  # from FAULT only disable leads out, as on the dVRK
    assert c.follower.wait_for(lambda: arm.operating_state().state == "DISABLED", 10.0), arm.operating_state()
    st = arm.ready(timeout=20.0)  # enabled again; still homed: no second homing
    assert st.ready
    arm.measured_js()  # in control again: no fault raised


def _fault_psm1_mid_run(served: ServedRig):
    """A friction ramp on PSM1 with its joint 1 pushed past its limit once the first force
    ramp is under way: the run's Outcome, and whether the fault was injected. It leaves
    PSM1 in FAULT, past its limit."""
    injected = threading.Event()

    def push_joint_1():
        served.client.operator.fault("PSM1", "joint_limit", joint=1)
        injected.set()

    served.changed.add("PSM1 faulted")
    out = served.run("friction-ramp", "--arm", "PSM1", "--ramp-time", "1.5", "--speeds", "0.01,0.02,0.04",
                     "--no-plots", when=("force ramp, positive direction [", push_joint_1))
    return out, injected.is_set()


def test_a_fault_mid_run_aborts_the_procedure_in_one_line(served):
    """It leaves PSM1 in FAULT, past its limit."""
    from rig.runs.recording import read_recording

    out, injected = _fault_psm1_mid_run(_fresh(served, ("PSM1 faulted",)))
    assert injected, out.stderr[-3000:]
    assert out.code == 3, out.stderr[-3000:]
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    line = out.last_line
    for words in ("rig friction-ramp: aborted:", "/PSM1/operating_state: PSM1 went to FAULT during the run",
                  "PSM1: joint 1 at", "past its limit", "run folder"):
        assert words in line, line
    assert "PSM1: ENABLED and homed" in out.stderr  # the procedure enabled and homed it when connecting
    doc = out.doc
    assert doc is not None and doc["status"] == "aborted" and "went to FAULT" in doc["error"], doc
    assert doc["step"] == "force ramp, positive direction", doc
    rec = read_recording(os.path.join(doc["run_dir"], "run.mcap"))
    assert rec.finalised and rec.stop["status"] == "aborted" and rec.stop["error"] == doc["error"]
    # an arm in FAULT obeys no command, the hold included: it is not counted as held
    assert rec.stop["held"] == [], rec.stop
    assert rec.stop["hold_errors"] and rec.stop["hold_errors"][0]["state"].startswith("FAULT"), rec.stop


def test_a_procedure_on_a_faulted_arm_stops_when_connecting(served):
    """PSM1 in FAULT (as the test above leaves it; faulted the same way first if it is
    not). A procedure does not clear a fault behind a person's back; it stops before its
    run, in one line."""
    if "PSM1 faulted" not in served.changed:
        out, injected = _fault_psm1_mid_run(served)
        assert injected and out.code == 3 and "went to FAULT" in out.last_line, out.stderr[-3000:]
    out = served.run("friction-ramp", "--arm", "PSM1", "--ramp-time", "1.5", "--speeds", "0.01,0.02,0.04",
                     "--no-plots")
    assert out.code == 3 and "Traceback" not in out.stderr, out.stderr[-3000:]
    assert "/PSM1/operating_state: PSM1 is FAULT; clear the fault at the dVRK console" in out.last_line, out.last_line
    assert "recording to" not in out.stderr  # stopped when connecting, before any run began
