"""A procedure that needs a faster arm stream than it hears says so in one line.

`rig sim` at the dVRK console's default ROS period (0.01 s: measured_js at 100 Hz) and a
procedure whose loop runs at 500 Hz (the default on ROS arms): it stops when connecting,
before anything moves, with one line naming the rate heard, the rate needed and the
console option to change. A procedure that moves no arm is not held to it. On simulated
time (`rig sim --sim-time`, `[ros] use_sim_time`), so the rate heard is the console's.
"""

from __future__ import annotations

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig, completed, lab_toml  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]


def test_a_slow_stream_is_refused_in_one_line(tmp_path):
    # on simulated time: the rate heard is counted over a window of the world's time, so it
    # is the console's, not what a loaded machine delivers in a window of the wall's
    with ServedRig(tmp_path, toml=lab_toml(tmp_path, sim_time=True), sim_args=("--ros-period", "0.01", "--no-mocap"),
                   sim_time=True) as rig:
        out = rig.run("loadcell-calibrate", "--seconds", "0.3")  # no arm: the stream rate does not matter
        completed(out, "loadcell-calibrate")
        out = rig.run("friction-ramp", "--no-plots")
        assert out.code == 3, out.stderr[-2000:]
        assert "Traceback" not in out.stderr
        line = out.last_line
        for words in ("/PSM1/measured_js", "heard at", "needs 500 Hz", "dvrk_system -p 0.002",
                      "rig sim --ros-period 0.002"):
            assert words in line, line
        heard = float(line.split("heard at ")[1].split(" Hz")[0])
        assert 50 <= heard <= 130, line  # 100 Hz, as the console publishes
