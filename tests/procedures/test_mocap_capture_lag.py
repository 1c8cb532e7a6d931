"""A motion's capture holds the tracker's frames of that motion, however late they come."""

from __future__ import annotations

import numpy as np

from drivers.interfaces import JointState, Pose, TrackerFrame
from procedures.mocap_capture import Collector, move_capture

DT = 0.01


class _Clock:
    overruns = skipped = 0   # the rig clock's counters (rig.devices.clock.Clock)

    def __init__(self):
        self.t = 100.0

    def tick(self):
        self.t += DT

    def now(self):
        return self.t


class _Arm:
    """Joint 2 moves toward its goal at 0.5 rad/s."""

    name = "PSM1"

    def __init__(self, clock):
        self.clock, self.q, self.goal = clock, np.zeros(3), np.zeros(3)

    def move_jp(self, goal, wait=False):
        self.goal = np.asarray(goal, float)

    def measured_js(self):
        step = np.clip(self.goal - self.q, -0.5 * DT, 0.5 * DT)
        self.q = self.q + step
        return JointState(self.clock.now(), self.q.copy(), step / DT, np.zeros(3))


class _LateTracker:
    """Frames of the arm's joint 2 (as the body's x position): prompt for the first 0.3 s,
    then each delivered `late` s after its stamp, as a stream held up on a loaded machine
    delivers them (the procedure cannot tell a constant lag from the offset of another
    computer's clock: a lag that starts after the stream did is what it can see)."""

    def __init__(self, clock, arm, late):
        self.clock, self.arm, self.late, self.made = clock, arm, late, []
        self.t0 = clock.now()

    def _due(self, f):
        return f.t + (0.0 if f.t < self.t0 + 0.3 else self.late)

    def frames(self):
        now = self.clock.now()
        self.made.append(TrackerFrame(now, {"pitch": Pose(now, np.array([self.arm.q[1], 0.0, 0.0]), np.eye(3))}))
        out = [f for f in self.made if self._due(f) <= now + 1e-9]
        self.made = [f for f in self.made if self._due(f) > now + 1e-9]
        return out


class _Recorder:
    def __getattr__(self, name):
        return lambda *a, **k: None


class _Run:
    recorder = _Recorder()


class _Rig:
    def __init__(self, late):
        self.clock = _Clock()
        self.arm = _Arm(self.clock)
        self.tracker = _LateTracker(self.clock, self.arm, late)


def _sweep(late):
    rig = _Rig(late)
    col = Collector("q2 sweep", ["pitch"])
    move_capture(rig, _Run(), rig.arm, [np.array([0.0, -0.4, 0.0]), np.array([0.0, 0.4, 0.0]),
                                        np.zeros(3)], col)
    x = np.array([f.bodies["pitch"].position[0] for f in col.frames])
    return x, col


def test_frames_a_second_late_stay_in_their_motions_capture():
    x, col = _sweep(late=1.0)
    # the whole sweep, -0.4 to 0.4 rad, is in this capture, back at rest at the end
    assert x.min() <= -0.399 and x.max() >= 0.399, (x.min(), x.max())
    assert abs(x[-1]) < 1e-9
    assert col.frames[-1].t >= col.js_t["PSM1"][-1] - 1.0 - 1e-9


def test_a_prompt_tracker_is_not_waited_for():
    x, col = _sweep(late=0.0)
    assert x.min() <= -0.399 and x.max() >= 0.399
    # no tick past the arrival: the last frame is the arrival's
    assert col.frames[-1].t == col.js_t["PSM1"][-1]
