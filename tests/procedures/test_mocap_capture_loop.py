"""The captures run on the run engine's control loop: what they record and what a Capture holds."""

from __future__ import annotations

import io

import numpy as np
import pytest

from drivers.interfaces import JointState, Pose, TrackerFrame
from procedures.mocap_capture import Collector, servo_capture, settle
from rig.runs.recording import read_recording
from rig.runs.run import Run

RATE = 100.0


class _Clock:
    rate = RATE
    overruns = skipped = 0

    def __init__(self):
        self.k = 0

    def tick(self):
        self.k += 1

    def now(self):
        return self.k / RATE


class _Arm:
    name = "PSM1"

    def __init__(self, clock):
        self.clock, self.q, self.sent = clock, np.array([0.0, 0.0, 0.1]), []

    def measured_js(self):
        return JointState(self.clock.now(), self.q.copy(), np.zeros(3), np.zeros(3), ("yaw", "pitch", "insertion"))

    def servo_jp(self, q):
        self.sent.append((self.clock.now(), np.array(q)))
        self.q = np.array(q, float)


class _Tracker:
    """The tool body at the arm's joint 3; occluded (and Marker1 lost) on tick 3, nothing
    delivered on tick 5 (a stale stream)."""

    bodies = ("tool",)

    def __init__(self, clock, arm):
        self.clock, self.arm = clock, arm

    def frames(self):
        k, t = self.clock.k, self.clock.now()
        if k == 5:
            return []
        p = np.array([0.0, 0.0, self.arm.q[2]])
        markers = {f"tool:Marker{i}": p + 0.01 * i for i in (1, 2, 3)}
        if k == 3:
            return [TrackerFrame(t, {"tool": None}, markers | {"tool:Marker1": None})]
        return [TrackerFrame(t, {"tool": Pose(t, p, np.eye(3))}, markers)]


class _Rig:
    def __init__(self):
        self.clock = _Clock()
        self.arm = _Arm(self.clock)
        self.tracker = _Tracker(self.clock, self.arm)


@pytest.fixture
def logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))


def test_a_held_capture_keeps_occluded_frames_as_nan_and_skips_a_stale_tick(logs):
    rig = _Rig()
    col = Collector("hold", ["tool"])
    with Run("capture", stream=io.StringIO()) as run:
        settle(rig, run, col, [rig.arm], 0.06)             # 6 ticks
    cap = col.capture()
    assert cap.t == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.06])   # tick 5 gave no frame
    R, p = cap.poses["tool"]
    assert np.isnan(p[2]).all() and np.isnan(R[2]).all()            # occluded on tick 3
    assert p[[0, 1, 3, 4], 2] == pytest.approx(0.1)
    X = cap.markers["tool"]
    assert np.isnan(X[2, 0]).all()                                   # Marker1 lost on tick 3
    np.testing.assert_allclose(X[2, 1:], [[0.02, 0.02, 0.12], [0.03, 0.03, 0.13]])
    assert col.js_t["PSM1"] == pytest.approx([k / RATE for k in range(1, 7)])
    rec = read_recording(run.dir / "run.mcap")
    counts = rec.counts()
    assert counts["/PSM1/measured_js"] == 6 and counts["/mocap/tool/pose"] == 4
    assert counts["/mocap/markers/tool/Marker1"] == 4 and counts["/mocap/markers/tool/Marker2"] == 5
    assert list(rec.messages["/PSM1/measured_js"][0][1].name) == ["yaw", "pitch", "insertion"]


def test_a_streamed_capture_sends_the_trajectory_each_period_and_records_what_was_measured(logs):
    rig = _Rig()
    col = Collector("stream", ["tool"])
    with Run("capture", stream=io.StringIO()) as run:
        servo_capture(rig, run, rig.arm, lambda s: np.array([0.0, 0.0, 0.1 + s]), 0.05, col)
    # one set-point a period, at the period's start, then the clock ticks: s = 0, 0.01, ... 0.04
    assert [t for t, _ in rig.arm.sent] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert [q[2] for _, q in rig.arm.sent] == pytest.approx([0.1, 0.11, 0.12, 0.13, 0.14])
    assert rig.clock.k == 5 and col.js_t["PSM1"] == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05])
    rec = read_recording(run.dir / "run.mcap")
    assert "/PSM1/servo_jp" not in rec.messages and rec.counts()["/PSM1/measured_js"] == 5
