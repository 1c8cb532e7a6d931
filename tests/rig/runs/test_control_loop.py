"""The run engine's control loop (rig.runs.control_loop): what it reads, records, checks and sends."""

from __future__ import annotations

import io

import numpy as np
import pytest

from drivers.interfaces import ForceSample, JointState
from rig.control.arm_command import ArmCommand, CommandKind
from rig.runs.control_loop import ControlLoop, body_topic, force_topic, marker_topic
from rig.runs.recording import read_recording
from rig.runs.run import AbortRun, Run
from rig.runs.safety import SafetyLimits


class Clock:
    rate = 100.0
    overruns = skipped = 0

    def __init__(self):
        self.k = 0
        self.listeners = []

    def tick(self):
        self.k += 1
        for fn in self.listeners:
            fn(self.now())

    def now(self):
        return self.k / self.rate


class Arm:
    """Two samples a tick (a 200 Hz stream read at 100 Hz); remembers its commands."""

    def __init__(self, name, clock):
        self.name, self.clock = name, clock
        self.samples, self.sent, self.holds = [], [], 0
        clock.listeners.append(self._publish)
        self._publish(0.0)

    def _publish(self, t):
        for dt in (-0.005, 0.0):
            q = np.array([0.0, 0.0, 0.1 + t + dt])
            self.samples.append(JointState(t + dt, q, np.zeros(3), np.zeros(3)))
        self._new = self.samples[-2:]

    def measured_js(self):
        return self.samples[-1]

    def drain_js(self):
        new, self._new = self._new, []
        return new

    def servo_jp(self, q, dq=None):
        self.sent.append(("jp", np.array(q)))

    def servo_jf(self, effort):
        self.sent.append(("jf", np.array(effort)))

    def hold(self):
        self.holds += 1


class Cell:
    def __init__(self, clock, force):
        self.clock, self.force, self.k = clock, force, 0

    def samples(self):
        t = self.clock.now()
        return [ForceSample(t - 0.002, self.force), ForceSample(t, self.force)]


@pytest.fixture
def logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    return tmp_path / "logs"


def test_each_tick_reads_drains_steps_checks_and_sends_in_order(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)
    seen = []

    def step(tick):
        seen.append((tick.k, tick.t, len(tick.joint_samples["PSM1"]), [len(f) for f in tick.forces]))
        return {"PSM1": ArmCommand(CommandKind.EFFORT, effort=np.array([0.0, 0.0, tick.k * 0.1]))}

    with Run("loop", stream=io.StringIO()) as run:
        loop = ControlLoop(run, clock, {"PSM1": arm}, limits=SafetyLimits(), sensors=[Cell(clock, 2.0)],
                           read="drain", loop_time_topic="/loop/time_us")
        assert loop.run(step, ticks=5) == 5
        timing = loop.timing()
    assert seen == [(k, (k + 1) / 100.0, 2, [2]) for k in range(5)]
    assert [e[2] for _, e in arm.sent] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert timing["t"] == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05]) and len(timing["compute_us"]) == 5
    rec = read_recording(run.dir / "run.mcap")
    counts = rec.counts()
    assert counts["/PSM1/measured_js"] == 10 and counts[force_topic(0)] == 10
    assert counts["/PSM1/servo_jf"] == 5 and counts["/loop/time_us"] == 5


def test_a_step_returning_none_ends_the_loop_after_that_tick(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)
    with Run("loop", stream=io.StringIO()) as run:
        loop = ControlLoop(run, clock, {"PSM1": arm})
        done = loop.run(lambda tick: None if tick.k == 3 else {}, ticks=None)
    assert done == 4 and clock.k == 4 and arm.sent == []


def test_a_breached_limit_aborts_before_the_command_goes_out(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)

    def step(tick):
        tick.tension = 4.0 if tick.k < 2 else 20.0     # above the 15 N ceiling on the third tick
        return {"PSM1": ArmCommand(CommandKind.POSITION, q=np.array([0.0, 0.0, 0.1]))}

    with pytest.raises(AbortRun, match="tension"):
        with Run("loop", stream=io.StringIO()) as run:
            run.claim(arm)
            ControlLoop(run, clock, {"PSM1": arm}, limits=SafetyLimits()).run(step, ticks=10)
    assert len(arm.sent) == 2 and arm.holds == 1


def test_an_effort_over_the_ceiling_is_never_sent(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)
    with pytest.raises(AbortRun):
        with Run("loop", stream=io.StringIO()) as run:
            ControlLoop(run, clock, {"PSM1": arm}, limits=SafetyLimits()).run(
                lambda tick: {"PSM1": ArmCommand(CommandKind.EFFORT, effort=np.array([0.0, 0.0, 99.0]))}, ticks=3)
    assert arm.sent == []


def test_the_arms_clock_is_watched_for_repeats_and_jumps(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)
    stamps = iter([0.01, 0.01, 0.08, 0.09])           # a repeat, then a 60 ms jump in a 10 ms tick
    arm.measured_js = lambda: JointState(next(stamps), np.zeros(3), np.zeros(3), np.zeros(3))
    with Run("loop", stream=io.StringIO()) as run:
        loop = ControlLoop(run, clock, {"PSM1": arm})
        loop.run(lambda tick: {}, ticks=4)
    timing = loop.timing()
    assert timing["repeated_js"] == 1 and timing["arm_clock_jumps"] == 1
    assert timing["arm_clock_jump_max"] == pytest.approx(0.06)
    # ages on the loop's clock: a console clock that jumped ahead reads as samples from the future
    assert timing["sample_age_ms"] == pytest.approx([0.0, 10.0, -50.0, -50.0], abs=1e-9)


class Tracker:
    """Mocap frames by tick: the tool body turning about z and its three markers; on tick 2
    the body is occluded and Marker2 lost, tick 3 delivers nothing (a stale stream), tick 4
    a burst of two frames."""

    bodies = ("tool",)

    def __init__(self, clock):
        self.clock, self.given = clock, []

    def _frame(self, t):
        from scipy.spatial.transform import Rotation

        from drivers.interfaces import Pose, TrackerFrame

        p = np.array([0.1, 0.2, 0.3 + t])
        R = Rotation.from_euler("z", 10.0 * t).as_matrix()
        markers = {f"tool:Marker{i}": p + 0.01 * i for i in (1, 2, 3)}
        if self.clock.k == 2:
            return TrackerFrame(t, {"tool": None}, markers | {"tool:Marker2": None})
        return TrackerFrame(t, {"tool": Pose(t, p, R)}, markers)

    def frames(self):
        t = self.clock.now()
        out = {3: [], 4: [self._frame(t - 0.005), self._frame(t)]}.get(self.clock.k, [self._frame(t)])
        self.given.append(out)
        return out


def test_the_tracker_is_drained_into_the_recording_frame_by_frame(logs):
    from scipy.spatial.transform import Rotation

    clock = Clock()
    arm = Arm("PSM1", clock)
    tracker = Tracker(clock)
    seen = []
    with Run("loop", stream=io.StringIO()) as run:
        loop = ControlLoop(run, clock, {"PSM1": arm}, tracker=tracker)
        loop.run(lambda tick: seen.append(tick.frames) or {}, ticks=5)
    # the step sees exactly what the tracker gave, tick by tick (none on the stale tick)
    assert len(seen) == 5 and all(s is g for s, g in zip(seen, tracker.given))
    assert [len(s) for s in seen] == [1, 1, 0, 2, 1]
    assert seen[1][0].bodies["tool"] is None                 # occluded: the step sees None
    frames = [f for s in seen for f in s]
    rec = read_recording(run.dir / "run.mcap")
    poses = rec.messages[body_topic("tool")]
    shown = [f for f in frames if f.bodies["tool"] is not None]
    assert len(poses) == len(shown) == 4                      # the occluded frame is not recorded
    for (t_ns, msg), f in zip(poses, shown):
        assert t_ns == round(f.t * 1e9)
        p, o = msg.pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z] == pytest.approx(f.bodies["tool"].position, abs=1e-12)
        q = Rotation.from_matrix(f.bodies["tool"].rotation).as_quat()
        assert abs(np.dot([o.x, o.y, o.z, o.w], q)) == pytest.approx(1.0, abs=1e-12)
        assert msg.header.frame_id == "mocap"
    m2 = rec.messages[marker_topic("tool:Marker2")]
    assert len(m2) == 4 and len(rec.messages[marker_topic("tool:Marker1")]) == 5
    assert [m.pose.position.z for _, m in m2] == pytest.approx(
        [f.markers["tool:Marker2"][2] for f in frames if f.markers["tool:Marker2"] is not None])


def test_joint_names_and_commands_are_recorded_as_asked(logs):
    clock = Clock()
    arm = Arm("PSM1", clock)
    named = JointState(0.0, np.zeros(3), np.zeros(3), np.zeros(3), ("yaw", "pitch", "insertion"))
    arm.measured_js = lambda: named
    with Run("loop", stream=io.StringIO()) as run:
        loop = ControlLoop(run, clock, {"PSM1": arm}, record_commands=False, joint_names=True)
        loop.run(lambda tick: {"PSM1": ArmCommand(CommandKind.POSITION, q=np.array([0.0, 0.0, 0.1]))}, ticks=2)
    rec = read_recording(run.dir / "run.mcap")
    assert "/PSM1/servo_jp" not in rec.messages and len(arm.sent) == 2    # sent, not recorded
    assert list(rec.messages["/PSM1/measured_js"][0][1].name) == ["yaw", "pitch", "insertion"]
