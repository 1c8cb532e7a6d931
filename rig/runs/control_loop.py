"""The control loop a procedure runs on the run engine: tick, read, step, check, send, time.

    loop = ControlLoop(run, rig.clock, {n: rig.arms[n] for n in names}, limits=limits,
                       sensors=cells)             # tracker=: a mocap Tracker drained too
    loop.prime()                                   # what the cells hold already, recorded
    loop.run(step, ticks=n, progress=st)           # step(tick) -> {arm: ArmCommand} or None

Each tick the loop

1. ticks the rig clock (rig.devices.clock: the physics step, the wall clock's next period,
   or the world's /clock in lockstep) and reads its time;
2. reads every arm (its newest measured_js, or every sample since the last tick with
   `read="drain"`), drains every force sensor and the mocap tracker's frames, recording
   all of it (a body occluded in a frame, or a marker lost, is not recorded in it; the
   step still sees the frame, the body None);
3. calls the procedure's step with a `Tick`: it computes the commands (timed with
   `tick.timed()`, or the whole step) and may set `tick.tension` and `tick.tips` for the
   limit checks; returning None ends the loop after this tick;
4. checks the limits (rig.runs.safety: the tension ceiling, each arm's joints, velocities,
   efforts and workspace; a breach raises AbortRun, and the run engine holds the arms);
5. sends each command (servo_jp, servo_jf, or servo_ci through the procedure's
   `impedance` sender) and records it (servo_jp and servo_jf unless `record_commands` is
   off: the mocap captures record what was measured only);
6. keeps the loop's timing: tick times, step compute times, the clock's overruns and
   skipped periods, ticks that found an arm's sample not renewed, jumps of the arms'
   clock and the age of their samples (`timing()`).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator, Protocol

import numpy as np

from drivers.common.quaternion import matrix_to_quat_xyzw
from drivers.interfaces import Tracker, TrackerFrame
from rig.control.arm_command import ArmCommand, CommandKind


class ImpedanceSender(Protocol):
    def send(self, arm: str, command: ArmCommand, t: float, recorder) -> None: ...


def force_topic(k: int) -> str:
    """The recording's topic of the k-th force sensor (the object's k-th element)."""
    return "/loadcell/force" if k == 0 else f"/loadcell{k}/force"


def body_topic(body: str) -> str:
    """The recording's topic of a mocap rigid body's pose."""
    return f"/mocap/{body}/pose"


def marker_topic(label: str) -> str:
    """The recording's topic of a labelled mocap marker ("body:Marker1"), a PoseStamped with
    the identity orientation: ROS 2 has no stamped point in the message set recorded."""
    return f"/mocap/markers/{label.replace(':', '/')}"


def record_frames(recorder, frames: list[TrackerFrame]) -> None:
    """Record mocap frames (drivers.interfaces.TrackerFrame): each seen body's pose and each
    seen marker, at the frame's time; an occluded body or a lost marker (None) is skipped."""
    for f in frames:
        seen = [(b, pose) for b, pose in f.bodies.items() if pose is not None]
        if seen:
            # one batched conversion per frame: per-body calls cost more than the physics
            quats = matrix_to_quat_xyzw(np.stack([pose.rotation for _, pose in seen]))
            for (b, pose), q in zip(seen, quats):
                recorder.pose(body_topic(b), f.t, pose.position, q, "mocap")
        for m, v in f.markers.items():
            if v is not None:
                recorder.pose(marker_topic(m), f.t, v, (0.0, 0.0, 0.0, 1.0), "mocap")


@dataclass
class Tick:
    """One period of the loop, as the step sees it (times in s on the rig clock)."""

    k: int
    t: float
    js: dict                                   # arm -> its newest JointState
    joint_samples: dict                        # arm -> every JointState since the last tick (read="drain")
    forces: list                               # per sensor, its new ForceSamples, oldest first
    frames: list = field(default_factory=list)  # the tracker's new TrackerFrames, oldest first
    tension: float | None = None               # N: set by the step, checked against the ceiling
    tips: dict = field(default_factory=dict)   # arm -> tool tip in the world (m): set by the step
    compute_s: float | None = None
    command_t: float | None = None             # the commands' time in the recording (default: t)
    last: bool = False                         # set by the step: its commands are the loop's last

    @contextmanager
    def timed(self) -> Iterator[None]:
        """Time the step's computation (the loop's figure) over the enclosed code."""
        c0 = time.perf_counter()
        try:
            yield
        finally:
            self.compute_s = (self.compute_s or 0.0) + time.perf_counter() - c0


class ArmClockWatch:
    """The arms' clock against the loop's. A sample stamped further on from the last one than
    the loop's own time moved is a jump of the console's clock (its servo loop fell behind
    and caught up, or rig sim re-anchored its time on a starved machine): the arm moved
    less than the stamps say. Counts those jumps (> 20 ms) and their largest, the ticks
    that found a sample not renewed, and how old the oldest arm's sample was when the
    loop acted on it."""

    JUMP = 0.02   # s

    def __init__(self, arms: list[str]):
        self.last = {n: None for n in arms}
        self.t_previous: float | None = None
        self.repeated = 0
        self.jumps = 0
        self.jump_max = 0.0
        self.ages_ms: list[float] = []

    def see(self, t: float, js: dict) -> None:
        for n, s in js.items():
            self.repeated += s.t == self.last[n]
            if self.last[n] is not None and self.t_previous is not None:
                jump = (s.t - self.last[n]) - (t - self.t_previous)
                self.jump_max = max(self.jump_max, jump)
                self.jumps += jump > self.JUMP
            self.last[n] = s.t
        self.t_previous = t
        self.ages_ms.append(1e3 * max(t - s.t for s in js.values()))


class ControlLoop:
    """A procedure's loop over `arms` (name -> Arm), `sensors` (ForceSensors, the object's
    elements in order) and `tracker` (a mocap Tracker) on `clock`, recorded by `run`; see
    the module docstring. `joint_names`: record each joint state's joint names too."""

    def __init__(self, run, clock, arms: dict, *, limits=None, sensors=(), tracker: Tracker | None = None,
                 read: str = "newest", impedance: ImpedanceSender | None = None,
                 loop_time_topic: str | None = None, record_commands: bool = True, joint_names: bool = False):
        if read not in ("newest", "drain"):
            raise ValueError(f"read must be 'newest' or 'drain', got {read!r}")
        self.run_ = run
        self.clock = clock
        self.arms = dict(arms)
        self.limits = limits
        self.sensors = list(sensors)
        self.tracker = tracker
        self.read = read
        self.record_commands = record_commands
        self.joint_names = joint_names
        self.impedance = impedance
        self.loop_time_topic = loop_time_topic
        self.watch = ArmClockWatch(list(self.arms))
        self._newest: dict = {}
        self.tick_t: list[float] = []
        self.compute_us: list[float] = []
        self.newest_force_t: list[float | None] = [None] * len(self.sensors)
        self._overruns0 = clock.overruns
        self._skipped0 = clock.skipped

    @property
    def recorder(self):
        return self.run_.recorder

    def prime(self) -> None:
        """Record what the sensors hold now: they have streamed since they were opened, and
        the first tick should not pay for it (three cells held ~3900 samples each after
        connecting; recording them took that tick 60 ms)."""
        self._drain_sensors()

    def _drain_sensors(self) -> list:
        out = []
        for k, sensor in enumerate(self.sensors):
            new = sensor.samples()
            topic = force_topic(k)
            for s in new:
                self.recorder.tension(topic, s.t, s.force)
            if new:
                last = self.newest_force_t[k]
                self.newest_force_t[k] = new[-1].t if last is None else max(last, new[-1].t)
            out.append(new)
        return out

    def _drain_tracker(self) -> list[TrackerFrame]:
        if self.tracker is None:
            return []
        frames = self.tracker.frames()
        record_frames(self.recorder, frames)
        return frames

    def _read_arms(self, t: float) -> tuple[dict, dict]:
        js, drained = {}, {}
        for n, arm in self.arms.items():
            if self.read == "drain":
                # every sample since the last tick (a tick held up by the machine finds
                # several); an arm with none keeps its newest (a silent stream is the
                # step's to judge, not a fault of the read)
                drained[n] = arm.drain_js()
                for s in drained[n]:
                    self._record_js(n, s)
                if drained[n]:
                    self._newest[n] = drained[n][-1]
                if n in self._newest:
                    js[n] = self._newest[n]
            else:
                js[n] = arm.measured_js()
                self._record_js(n, js[n])
        if len(js) == len(self.arms):
            self.watch.see(t, js)
        return js, drained

    def _record_js(self, arm: str, s) -> None:
        self.recorder.joint_state(f"/{arm}/measured_js", s.t, s.position, s.velocity, s.effort,
                                  s.name if self.joint_names else ())

    def send(self, commands: dict, t: float) -> None:
        """Send each arm's command (checking a commanded effort against the limits first) and
        record it (`record_commands`)."""
        rec = self.recorder if self.record_commands else None
        for n, cmd in commands.items():
            arm = self.arms[n]
            if cmd.kind == CommandKind.POSITION:
                if cmd.dq is None:
                    arm.servo_jp(cmd.q)
                else:
                    arm.servo_jp(cmd.q, cmd.dq)
                if rec is not None:
                    rec.joint_state(f"/{n}/servo_jp", t, cmd.q, () if cmd.dq is None else cmd.dq, ())
            elif cmd.kind == CommandKind.IMPEDANCE:
                if self.limits is not None:
                    self.limits.check_effort(n, cmd.feedforward)
                self.impedance.send(n, cmd, t, self.recorder)  # it records what it sends
            else:
                if self.limits is not None:
                    self.limits.check_effort(n, cmd.effort)
                arm.servo_jf(cmd.effort)
                if rec is not None:
                    rec.joint_state(f"/{n}/servo_jf", t, (), (), cmd.effort)

    def _check(self, tick: Tick, commands: dict) -> None:
        """The limits of this tick, arm by arm just before its command goes out."""
        if self.limits is not None and tick.tension is not None:
            self.limits.check_tension(tick.tension)
        for n in self.arms:
            if self.limits is not None and n in tick.tips:
                s = tick.js[n]
                self.limits.check_arm(n, s.position[:3], s.velocity[:3], s.effort[:3], tick.tips[n])
            if n in commands:
                self.send({n: commands[n]}, tick.t if tick.command_t is None else tick.command_t)

    def run(self, step: Callable[[Tick], dict | None], ticks: int | None = None, progress=None,
            every: int = 100, on_progress: Callable[[Tick], None] | None = None, tick_last: bool = False) -> int:
        """Run `ticks` periods (None: until the step returns None or sets `tick.last`);
        returns the ticks done. `progress`: a run step (rig.runs.run.Step) updated every
        `every` ticks, when `on_progress(tick)` is called too. `tick_last`: the clock ticks
        at the end of each period (read, step, send, tick: commands computed from the state
        of now), not at its start, and not after a period whose step ended the loop."""
        k = 0
        while ticks is None or k < ticks:
            if not tick_last:
                self.clock.tick()
            t = self.clock.now()
            js, drained = self._read_arms(t)
            tick = Tick(k, t, js, drained, self._drain_sensors(), self._drain_tracker())
            c0 = time.perf_counter()
            commands = step(tick)
            compute = tick.compute_s if tick.compute_s is not None else time.perf_counter() - c0
            self._check(tick, commands or {})
            self.tick_t.append(t)
            self.compute_us.append(compute * 1e6)
            if self.loop_time_topic is not None:
                self.recorder.scalar(self.loop_time_topic, t, compute * 1e6)
            k += 1
            if tick.k % every == 0:
                if progress is not None:
                    progress.update(tick.k)
                if on_progress is not None:
                    on_progress(tick)
            if commands is None or tick.last:
                break
            if tick_last:
                self.clock.tick()
        if progress is not None and k == ticks:
            progress.update(ticks)
        return k

    def timing(self) -> dict:
        """The raw figures of the ticks done: times (s), compute (us), the clock's overruns
        and skipped periods since the loop was made, and the arms' clock (ArmClockWatch)."""
        return {"t": np.asarray(self.tick_t), "compute_us": np.asarray(self.compute_us),
                "overruns": self.clock.overruns - self._overruns0,
                "skipped": self.clock.skipped - self._skipped0,
                "repeated_js": self.watch.repeated, "arm_clock_jumps": self.watch.jumps,
                "arm_clock_jump_max": self.watch.jump_max,
                "sample_age_ms": np.asarray(self.watch.ages_ms[:len(self.tick_t)])}
