"""`rig cooperative --ros-commands`: another program steers the object over ROS 2.

The procedure runs as `rig cooperative` in a subprocess on the simulated rig paced to the
wall clock (rig.pace = true), so that messages arrive while it holds the object; this test
process is the other program: its own rclpy context and node publish /psm/cmd_vel and
/psm/cmd_force. Two processes are the real claim (any device or program that publishes
them can steer the object) and cost only the subprocess start (~3 s). Both get a private
ROS_DOMAIN_ID (claimed for the test: tests/conftest.py's ros_env) and localhost-only
discovery.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import rclpy  # noqa: E402  (a declared dependency: a broken install fails here)
from geometry_msgs.msg import Twist  # noqa: E402
from rclpy.context import Context  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from rig import config  # noqa: E402
from rig.model import psm_kinematics as K  # noqa: E402
from rig.runs.recording import read_recording  # noqa: E402

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
ARMS = ("PSM1", "PSM2")


class _Procedure:
    """`rig cooperative --ros-commands` in a subprocess; its stderr is read as it comes, so
    the test can tell how far the control loop is on the rig's clock (the step's progress
    lines, one per 10 %: ticks done / total)."""

    def __init__(self, tmp_path: Path, settle: float, hold_after: float):
        self.proc = _start(tmp_path, settle, hold_after)
        self.out_lines: list[str] = []
        self.err_lines: list[str] = []
        self.readers = [threading.Thread(target=self._read, args=(stream, lines), daemon=True)
                        for stream, lines in ((self.proc.stdout, self.out_lines), (self.proc.stderr, self.err_lines))]
        for r in self.readers:
            r.start()

    @staticmethod
    def _read(stream, lines: list[str]) -> None:
        for line in stream:
            lines.append(line)

    @property
    def stderr(self) -> str:
        return "".join(self.err_lines)

    def wait_for_loop_time(self, seconds: float, rate: float, timeout: float) -> None:
        """Return once the hold loop has run `seconds` of rig time."""
        pattern = re.compile(r"hold the tension while moving \[[#-]+\] (\d+)/(\d+)")
        deadline = time.monotonic() + timeout
        while True:
            done = [int(m.group(1)) for line in list(self.err_lines) if (m := pattern.search(line))]
            if done and done[-1] >= seconds * rate:
                return
            if self.proc.poll() is not None:
                pytest.fail(f"rig cooperative exited ({self.proc.returncode}) early: {self.stderr[-2000:]}")
            assert time.monotonic() < deadline, f"the loop did not reach {seconds} s: {self.stderr[-2000:]}"
            time.sleep(0.02)

    def finish(self, timeout: float) -> tuple[dict, str]:
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f"rig cooperative did not finish in {timeout} s: {self.stderr[-2000:]}")
        for r in self.readers:
            r.join(timeout=5.0)
        docs = [line for line in self.out_lines if line.startswith("{")]
        assert docs, f"no JSON result (exit {self.proc.returncode}): {self.stderr[-3000:]}"
        return json.loads(docs[-1]), self.stderr

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def _start(tmp_path: Path, settle: float, hold_after: float) -> subprocess.Popen:
    (tmp_path / "rig.toml").write_text("[rig]\npace = true\n")
    # this checkout's packages, not whatever copy the environment has installed
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "cooperative", "--ros-commands", "--force", "5", "--move", "0,0,0",
         "--duration", "0.5", "--settle", str(settle), "--hold-after", str(hold_after), "--json"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


class _Teleop:
    """A separate program's node publishing the two command topics."""

    def __init__(self):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("test_teleop", context=self.ctx)
        self.vel = self.node.create_publisher(Twist, "/psm/cmd_vel", 10)
        self.force = self.node.create_publisher(Float64, "/psm/cmd_force", 10)

    def wait_for_subscriber(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while self.vel.get_subscription_count() == 0 or self.force.get_subscription_count() == 0:
            assert time.monotonic() < deadline, "rig cooperative never subscribed to /psm/cmd_vel and /psm/cmd_force"
            time.sleep(0.02)

    def twist(self, linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0)) -> None:
        m = Twist()
        m.linear.x, m.linear.y, m.linear.z = map(float, linear)
        m.angular.x, m.angular.y, m.angular.z = map(float, angular)
        self.vel.publish(m)

    def tension(self, increment: float) -> None:
        self.force.publish(Float64(data=float(increment)))

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def teleop(ros_env):
    t = _Teleop()
    yield t
    t.close()


def _tips(rec, cfg) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each arm's measured tool tip in the world: (times s, positions m), from the recording."""
    out = {}
    for n in ARMS:
        T = cfg.base_matrix(n) @ K.RCM_FRAME
        msgs = rec.messages[f"/{n}/measured_js"]
        t = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in msgs])
        x = np.array([T[:3, 3] + T[:3, :3] @ K.tip_in_rcm(np.array(m.position[:3])) for _, m in msgs])
        out[n] = (t, x)
    return out


def _mean_over(t, values, t0, t1):
    sel = (t >= t0) & (t < t1)
    assert sel.any(), f"no samples in [{t0:.3f}, {t1:.3f}) s"
    return values[sel].mean(axis=0)


def test_help_gives_the_topics_and_their_units():
    from click.testing import CliRunner

    from rig.cli import main

    text = " ".join(CliRunner().invoke(main, ["cooperative", "--help"]).output.split())
    for words in ("/psm/cmd_vel geometry_msgs/Twist", "linear = Cartesian increment of the object in m (world frame)",
                  "angular = object Euler-angle (x-y-z) increment in rad",
                  "/psm/cmd_force std_msgs/Float64 = tension increment in N"):
        assert words in text


def test_published_increments_move_the_object_and_raise_the_tension(tmp_path, teleop):
    settle, hold_after = 2.0, 4.5
    proc = _Procedure(tmp_path, settle, hold_after)
    try:
        # Once the tension holds 5 N and the (empty) planned motion is over, one increment
        # of each kind; some 4 s of the run are left to follow them.
        proc.wait_for_loop_time(2.8, rate=1000.0, timeout=40.0)
        teleop.wait_for_subscriber(timeout=30.0)  # a guard against a hang
        teleop.twist(linear=(0.0, 0.01, 0.0))
        teleop.tension(1.0)
        result, err = proc.finish(timeout=60.0)
    finally:
        proc.kill()
    assert proc.proc.returncode == 0 and result["status"] == "completed", err[-3000:]
    live = result["live_commands"]
    assert live["received"]["/psm/cmd_vel"] == 1 and live["received"]["/psm/cmd_force"] == 1, live
    assert live["applied"]["/psm/cmd_vel"] == 1 and live["applied"]["/psm/cmd_force"] == 1, live
    assert live["rejected"] == []
    assert live["offset_translation"] == pytest.approx([0.0, 0.01, 0.0])
    assert live["force_offset"] == pytest.approx(1.0)
    assert live["last_applied"] > settle + 0.5
    # figures against the live set-point: the step to 6 N is neither an error nor a limit cycle
    assert result["max_error_during_motion"] < 0.25 and not result["limit_cycle"]
    assert result["hold_peak_to_peak"] < 0.5

    rec = read_recording(Path(result["run_dir"]) / "run.mcap")
    assert rec.finalised and rec.stop["status"] == "completed"
    (t_vel, vel), = rec.messages["/psm/cmd_vel"]
    (t_force, force), = rec.messages["/psm/cmd_force"]
    assert (vel.linear.x, vel.linear.y, vel.linear.z) == (0.0, 0.01, 0.0) and force.data == 1.0
    t_cmd = max(t_vel, t_force) * 1e-9
    setpoints = rec.messages["/cooperative/force_setpoint"]
    t_end = setpoints[-1][0] * 1e-9
    # Enough of the run left to settle: the start-up ramp settles a 5 N step in ~1 s.
    assert t_end - t_cmd > 3.0, f"the commands arrived {t_end - t_cmd:.2f} s before the end"
    before = [v.data for ts, v in setpoints if ts * 1e-9 < t_cmd]
    assert before[-1] == pytest.approx(5.0) and setpoints[-1][1].data == pytest.approx(6.0)

    loadcell = rec.messages["/loadcell/force"]
    tf = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in loadcell])
    F = np.array([m.wrench.force.x for _, m in loadcell])
    # Before: holding 5 N; in the last second: 6 N. Means within 0.1 N (the loop's
    # deadband is 0.02 N and the load cell's noise 0.02 N rms, so a settled loop sits well
    # inside; a loop still on its way from 5 N is not); every sample within the issue's
    # 0.25 N bound.
    assert _mean_over(tf, F, t_cmd - 0.5, t_cmd) == pytest.approx(5.0, abs=0.1)
    assert _mean_over(tf, F, t_end - 1.0, t_end + 1.0) == pytest.approx(6.0, abs=0.1)
    assert np.abs(F[tf > t_end - 1.0] - 6.0).max() < 0.25

    cfg = config.load(tmp_path / "rig.toml")
    tips = _tips(rec, cfg)
    for n in ARMS:
        t, x = tips[n]
        moved = _mean_over(t, x, t_end - 0.5, t_end + 1.0) - _mean_over(t, x, t_cmd - 0.2, t_cmd)
        # 1 cm in y, across the object: both tips follow to within 0.5 mm (the master's
        # PID holds its set-point to about that under the object's pull; across the object
        # the slave's impedance is 400 N/m, so 0.5 mm would take a 0.2 N force error).
        assert moved[1] == pytest.approx(0.01, abs=5e-4), (n, moved)
        # Otherwise the tips move only by the extra 1 N: the spring stretches 1 N / 2450 N/m
        # = 0.4 mm along the object and the master's PID gives way by about as much.
        others = moved - moved[1] * np.array([0.0, 1.0, 0.0])
        assert np.linalg.norm(others) < 1e-3, (n, moved)


def test_bad_increments_are_refused_and_the_object_stays_held(tmp_path, teleop):
    # docs/safety.md, "Bad input": a NaN, or an increment that would take a target out of the
    # workspace box or the tension set-point above the ceiling, is refused before anything
    # moves, counted and reported; the run keeps holding and completes.
    settle, hold_after = 1.5, 2.0
    proc = _Procedure(tmp_path, settle, hold_after)
    try:
        proc.wait_for_loop_time(1.5, rate=1000.0, timeout=40.0)
        teleop.wait_for_subscriber(timeout=30.0)  # a guard against a hang
        teleop.twist(linear=(float("nan"), 0.0, 0.0))
        teleop.twist(linear=(0.0, 0.5, 0.0))        # y = 0.5 m: outside the box (|y| <= 0.35 m)
        teleop.tension(20.0)                        # 25 N: above the 15 N ceiling
        result, err = proc.finish(timeout=60.0)
    finally:
        proc.kill()
    assert proc.proc.returncode == 0 and result["status"] == "completed", err[-3000:]
    live = result["live_commands"]
    assert live["received"]["/psm/cmd_vel"] == 2 and live["received"]["/psm/cmd_force"] == 1, live
    assert live["applied"]["/psm/cmd_vel"] == 0 and live["applied"]["/psm/cmd_force"] == 0, live
    reasons = {r["source"]: [] for r in live["rejected"]}
    for r in live["rejected"]:
        reasons[r["source"]].append(r["reason"])
    assert len(reasons["/psm/cmd_vel"]) == 2 and len(reasons["/psm/cmd_force"]) == 1, live["rejected"]
    assert "not a finite number" in reasons["/psm/cmd_vel"][0]
    assert "workspace box" in reasons["/psm/cmd_vel"][1] or "cannot reach" in reasons["/psm/cmd_vel"][1]
    assert "25.00 N" in reasons["/psm/cmd_force"][0]
    assert err.count("refused") == 4       # three lines as they come, and the report
    assert "live commands: 3 received, 0 applied, 3 refused" in err
    assert live["offset_translation"] == [0.0, 0.0, 0.0] and live["force_offset"] == 0.0

    rec = read_recording(Path(result["run_dir"]) / "run.mcap")
    assert rec.finalised and rec.stop["status"] == "completed"
    vel = [m for _, m in rec.messages["/psm/cmd_vel"]]      # refused messages are recorded too
    assert np.isnan(vel[0].linear.x) and vel[1].linear.y == 0.5
    t_cmd = rec.messages["/psm/cmd_force"][0][0] * 1e-9
    setpoints = rec.messages["/cooperative/force_setpoint"]
    t_end = setpoints[-1][0] * 1e-9
    assert all(v.data == pytest.approx(5.0) for ts, v in setpoints if ts * 1e-9 >= t_cmd)
    loadcell = rec.messages["/loadcell/force"]
    tf = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in loadcell])
    F = np.array([m.wrench.force.x for _, m in loadcell])
    assert np.abs(F[tf >= t_cmd] - 5.0).max() < 0.25
    tips = _tips(rec, config.load(tmp_path / "rig.toml"))
    for n in ARMS:
        t, x = tips[n]
        moved = _mean_over(t, x, t_end - 0.5, t_end + 1.0) - _mean_over(t, x, t_cmd - 0.2, t_cmd)
        # held where they were: within 1 mm (the master's PID still gives way by ~0.5 mm
        # as the tension settles; the refused translation was 0.5 m)
        assert np.linalg.norm(moved) < 1e-3, (n, moved)
