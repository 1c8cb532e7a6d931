"""Moving arms while the mocap system watches: what the kinematic calibration procedures share.

`rig link-lengths`, `rig calibrate-rcm` and `rig register` all move one joint (or two)
through a range while an optical tracker records marker bodies on the links. This module
holds that part, written against the device interfaces only (drivers/interfaces.py: Arm,
Tracker, and a Clock), so the same code drives the real rig and the simulated one:

* `Capture`: the mocap frames (body poses, labelled markers) and arm joint states of one
  phase of a procedure, as arrays, with the joint positions interpolated to frame times;
* `move_capture` / `servo_capture` / `settle`: move an arm (move_jp, or a streamed servo_jp
  trajectory), or hold the arms, on the run engine's control loop, which ticks the clock
  and records every joint state and mocap frame to the run's MCAP; the loop's step takes
  them into a Capture;
* `body_points`: a body's markers (N, P, 3), or, when the tracker gives poses only (ROS
  bridges publish PoseStamped per body), three virtual points rigidly attached to the
  pose, so the thesis's three-marker fits run on either;
* `open_devices`: the clock, arms, tracker and operator of a configuration (the operator,
  drivers.operator.driver, does the steps a person does on the real rig: mount bodies, touch a
  point).

Units: m, rad (joint 3 in m), s.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Callable

import numpy as np

from calibration.captures import Capture
from drivers.interfaces import TrackerFrame
from rig.commands.exit_codes import InputError
from rig.control.arm_command import ArmCommand, CommandKind
from rig.runs.control_loop import ControlLoop
from rig.runs.run import AbortRun

# A move has arrived when the measured joints are this close to the goal and at rest. Looser
# than the dVRK's own move_jp tolerance: under gravity the pitch joint settles a few mrad
# short until the integral term catches up, which does not matter to a calibration sweep
# (the measured joints are recorded, not the commanded ones).
ARRIVED = np.array([6e-3, 6e-3, 3e-3])     # rad, rad, m
AT_REST = np.array([0.03, 0.03, 0.005])     # rad/s, rad/s, m/s
#: s a motion waits, once the arm is at its goal, for the tracker's frames of the motion
#: (a stream held up by a loaded machine delivers them later, in a burst)
CATCH_UP_S = 3.0


# ------------------------------------------------------------------------------ capture


class Collector:
    """Accumulates frames and joint samples of one phase, then makes a Capture."""

    def __init__(self, name: str, bodies: list[str]):
        self.name = name
        self.bodies = bodies
        self.frames: list[TrackerFrame] = []
        self.js_t: dict[str, list[float]] = {}
        self.js_q: dict[str, list[np.ndarray]] = {}

    def add_js(self, arm: str, t: float, q: np.ndarray) -> None:
        self.js_t.setdefault(arm, []).append(float(t))
        self.js_q.setdefault(arm, []).append(np.asarray(q, float)[:3].copy())

    def capture(self) -> Capture:
        n = len(self.frames)
        t = np.array([f.t for f in self.frames], float)
        poses, markers = {}, {}
        for b in self.bodies:
            R = np.full((n, 3, 3), np.nan)
            p = np.full((n, 3), np.nan)
            for k, f in enumerate(self.frames):
                pose = f.bodies.get(b)
                if pose is not None:
                    R[k], p[k] = pose.rotation, pose.position
            poses[b] = (R, p)
            labels = sorted((m for m in (self.frames[0].markers if n else {}) if m.startswith(b + ":")),
                            key=_marker_index)
            if len(labels) >= 3:
                X = np.full((n, len(labels), 3), np.nan)
                for k, f in enumerate(self.frames):
                    for j, m in enumerate(labels):
                        v = f.markers.get(m)
                        if v is not None:
                            X[k, j] = v
                markers[b] = X
        joints, js = {}, {}
        for arm, ts in self.js_t.items():
            tq = np.array(ts)
            q = np.array(self.js_q[arm])
            js[arm] = (tq, q)
            joints[arm] = np.stack([np.interp(t, tq, q[:, j]) for j in range(3)], axis=1) if n else np.zeros((0, 3))
        return Capture(self.name, t, poses, markers, joints, js)


def _marker_index(label: str) -> int:
    tail = label.rsplit("Marker", 1)[-1]
    return int(tail) if tail.isdigit() else 0


# ------------------------------------------------------------------------------ moving
# Every motion runs on the run engine's control loop (rig.runs.control_loop): it ticks the
# clock, reads each arm's newest joint state and drains the tracker's frames into the
# recording (joint names included, the commands not: a capture records what was measured);
# the step here takes them into the phase's Collector.

def _loop(rig, run, arms: list) -> ControlLoop:
    return ControlLoop(run, rig.clock, {a.name: a for a in arms}, tracker=rig.tracker,
                       record_commands=False, joint_names=True)


def _collect(rig, collector: Collector, tick) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Take one tick's joint states and mocap frames into `collector`; each arm's (q, dq),
    joints 1-3."""
    q = {}
    for name, js in tick.js.items():
        collector.add_js(name, js.t, js.position)
        q[name] = (np.asarray(js.position, float)[:3], np.asarray(js.velocity, float)[:3])
    if tick.frames:
        lag = _TrackerLag.of(rig.tracker)
        lag.smallest = min(lag.smallest, rig.clock.now() - tick.frames[-1].t)
        lag.newest = max(lag.newest, tick.frames[-1].t)
    collector.frames.extend(tick.frames)
    return q


class _TrackerLag:
    """Per tracker: its newest frame's stamp, and the smallest (clock time - stamp) seen
    when frames were taken (the offset of the tracker's clock, which may be another
    computer's, plus the quickest way here)."""

    def __init__(self) -> None:
        self.smallest = math.inf
        self.newest = -math.inf

    @staticmethod
    def of(tracker) -> "_TrackerLag":
        try:
            return _LAGS.setdefault(tracker, _TrackerLag())
        except TypeError:  # a tracker that cannot be weakly referenced: no memory across calls
            return _TrackerLag()


#: each tracker's _TrackerLag, for as long as the tracker lives
_LAGS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _catch_up(rig, run, collector: Collector, arms: list) -> None:
    """Keep ticking (the arms at rest) until the tracker has delivered its frames up to
    now, at most CATCH_UP_S: a phase's motion then lies in its own capture. On a loaded
    machine the mocap's frames reached the procedure up to seconds late, in bursts: the
    q2 sweep's frames fell into the next phase, and its capture held 4 deg of a 46 deg
    sweep (the axis fit refused it)."""
    t_end = rig.clock.now()
    lag = _TrackerLag.of(rig.tracker)
    if not math.isfinite(lag.smallest):
        return
    deadline = t_end + CATCH_UP_S

    def behind() -> bool:
        return lag.newest + lag.smallest < t_end and rig.clock.now() < deadline

    def step(tick):
        _collect(rig, collector, tick)
        return {} if behind() else None

    if behind():
        _loop(rig, run, arms).run(step)


def move_capture(rig, run, arm, goals: list[np.ndarray], collector: Collector,
                 step=None, timeout: float = 30.0, others: list | None = None) -> None:
    """move_jp `arm` through `goals` in turn, recording everything until each arrives.

    Arrival: measured joints within ARRIVED of the goal and slower than AT_REST; a goal
    not reached within `timeout` s of clock time aborts the run (the arm is then held).
    `others`: further arms whose joint states are recorded too.
    """
    arms = [arm] + list(others or [])
    for i, goal in enumerate(goals):
        goal = np.asarray(goal, float)
        arm.move_jp(goal, wait=False)
        t_end = rig.clock.now() + timeout

        def arrive(tick):
            q, dq = _collect(rig, collector, tick)[arm.name]
            if np.all(np.abs(q - goal) <= ARRIVED) and np.all(np.abs(dq) <= AT_REST):
                return None
            if rig.clock.now() > t_end:
                err = q - goal
                raise AbortRun(f"{arm.name} did not reach {np.round(goal, 4).tolist()} within "
                               f"{timeout:.0f} s (error {np.round(err, 4).tolist()} rad, rad, m)")
            return {}

        _loop(rig, run, arms).run(arrive)
        if i == len(goals) - 1:
            _catch_up(rig, run, collector, arms)
        if step is not None:
            step.advance()


def servo_capture(rig, run, arm, trajectory: Callable[[float], np.ndarray], duration: float,
                  collector: Collector, step=None) -> None:
    """Stream servo_jp(trajectory(s)) for s in [0, duration] s of clock time, recording.

    trajectory: s -> (3,) joints; it must start where the arm is and respect the limits.
    Each period sends the trajectory at the period's start, then the clock ticks.
    """
    t0 = rig.clock.now()
    n = int(round(duration * rig.clock.rate))
    if n <= 0:
        return
    shown = 0

    def command() -> dict:
        return {arm.name: ArmCommand(CommandKind.POSITION, q=trajectory(rig.clock.now() - t0))}

    def stream(tick):
        nonlocal shown
        _collect(rig, collector, tick)
        if step is not None and step.total:
            done = int(step.total * (tick.k + 1) / n)
            if done > shown:
                step.advance(done - shown)
                shown = done
        # the next period's set-point, sent now (the last period's set-point was its last)
        return command() if tick.k + 1 < n else {}

    loop = _loop(rig, run, [arm])
    loop.send(command(), t0)
    loop.run(stream, ticks=n)


def settle(rig, run, collector: Collector, arms: list, duration: float) -> None:
    """Tick for `duration` s recording (arms holding where they are)."""
    n = int(round(duration * rig.clock.rate))

    def hold(tick):
        _collect(rig, collector, tick)
        return {}

    if n > 0:
        _loop(rig, run, arms).run(hold, ticks=n)


# ------------------------------------------------------------------------------ people
# The steps that need a person are asked of the rig's operator (drivers.operator.driver): the
# console on the real rig, `rig sim`'s operator over ROS 2, or the in-process simulation.


@dataclass
class Devices:
    """The devices a calibration procedure uses: clock, arms by name, tracker, person;
    `world` is the simulated world when the rig is simulated (for truth only), else None."""

    clock: object
    arms: dict
    tracker: object
    person: object  # drivers.interfaces.Operator
    world: object = None
    rig: object = None

    def close(self) -> None:
        if self.rig is not None:
            self.rig.close()


def tracker_stats(tracker) -> dict:
    """The tracker's counters (frames, incomplete, late, dropped...; drivers.mocap.ros_tracker.MocapStats)
    for a run's result: frames lost on the way are reported, never hidden (docs/recordings.md)."""
    if tracker is None:
        return {}
    return {k: v for k, v in vars(tracker.stats).items() if isinstance(v, (int, float, dict))}


def open_devices(cfg, seed: int | None = None, arms: list[str] | None = None) -> Devices:
    """The configuration's clock, arms, tracker and operator (`rig.devices.factory.open_rig`; no
    load cell): the operator does the manual steps (the simulation itself on the simulated
    rig, `rig sim`'s operator or the person at the console on a ROS rig; `yes` answers the
    console's requests)."""
    from rig.devices.factory import open_rig

    rig = open_rig(cfg, arms, seed=seed, uses=("mocap",))
    if rig.tracker is None:
        rig.close()
        raise InputError(f"{cfg.source}: no motion-capture system ([mocap] driver = 'none'); "
                                   "this procedure tracks marker bodies")
    return Devices(rig.clock, dict(rig.arms), rig.tracker, rig.operator, rig.world, rig)


# ------------------------------------------------------------------ RCM calibration phases
#: the steps of an arm's RCM calibration, as `rig calibrate-rcm` and `rig register` name them
RCM_PHASES = ("power on and home the arm", "sweep q1 with q2 = 0", "sweep q2 with q1 = 0",
              "Lissajous of q1 and q2 through the workspace")


def lissajous(q1a: float, q2a: float, q3: float, duration: float):
    """q(s) for s in [0, duration] s: a Lissajous figure, q1 two periods and q2 three,
    under a raised-cosine envelope so it starts and ends at rest at q1 = q2 = 0; and its
    peak joint speed (rad/s, sampled), to check against Table 4.2 before anything moves."""
    w = 2 * math.pi / max(duration, 1e-9)
    ramp = min(2.0, duration / 4)

    def q(s: float) -> np.ndarray:
        e = 1.0
        if s < ramp:
            e = 0.5 - 0.5 * math.cos(math.pi * s / ramp)
        elif s > duration - ramp:
            e = 0.5 - 0.5 * math.cos(math.pi * max(duration - s, 0.0) / ramp)
        return np.array([e * q1a * math.sin(2 * w * s), e * q2a * math.sin(3 * w * s), q3])

    if duration <= 0:
        return q, 0.0
    ss = np.linspace(0.0, duration, 2001)
    Q = np.array([q(x) for x in ss])
    vmax = float(np.max(np.abs(np.diff(Q[:, :2], axis=0)) / (ss[1] - ss[0])))
    return q, vmax


def measure_rcm_phases(dev, run, arm_name: str, parameters: dict, bodies: list[str]) -> dict[str, Capture]:
    """The phases of one arm's RCM calibration (appendix A.2), each a step of `run` named
    after RCM_PHASES: home, sweep q1, sweep q2 and, with parameters["duration"] > 0, the
    Lissajous figure (moves the arm; records into the run). `parameters`: q1_range,
    q2_range (rad), q3 (m), duration (s)."""
    arm = run.claim(dev.arms[arm_name])
    q3 = parameters["q3"]
    zero = np.array([0.0, 0.0, q3])
    caps = {}
    with run.step(f"{RCM_PHASES[0]} ({arm_name})"):
        home = Collector("home", bodies)
        move_capture(dev, run, arm, [zero], home)
    for key, j, label in (("q1", 0, RCM_PHASES[1]), ("q2", 1, RCM_PHASES[2])):
        amp = parameters[f"q{j + 1}_range"]
        goals = []
        for s in (-1, 1):
            g = zero.copy()
            g[j] = s * amp
            goals.append(g)
        goals.append(zero)
        col = Collector(f"{key} sweep", bodies)
        with run.step(f"{label} ({arm_name})", total=len(goals)) as st:
            move_capture(dev, run, arm, goals, col, step=st)
        caps[key] = col.capture()
    if parameters["duration"] > 0:
        traj, _ = lissajous(parameters["q1_range"], parameters["q2_range"], q3, parameters["duration"])
        col = Collector("lissajous", bodies)
        with run.step(f"{RCM_PHASES[3]} ({arm_name})", total=20) as st:
            servo_capture(dev, run, arm, traj, parameters["duration"], col, step=st)
            move_capture(dev, run, arm, [zero], col)
        caps["lissajous"] = col.capture()
    return caps
