"""dVRK 2.3 names its console topics /console/..., dVRK 2.4 /system/...: `rig sim` serves
either, and a RosArm with console="auto" (the [ros] console default) finds which from the
ROS graph and reaches the console that is there."""

from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]


@pytest.mark.parametrize("console", ["/system", "/console"])
def test_auto_finds_the_console_rig_sim_serves(tmp_path, ros_env, console):
    from drivers.arm.dvrk_arm import RosArm
    from drivers.common.ros_session import RosSession

    with ServedRig(tmp_path, ros_env, toml='[arms.PSM1]\ndriver = "ros"\n',
                   sim_args=("--console", console, "--no-loadcell", "--no-mocap")):
        session = RosSession("console_probe")
        arm = RosArm(session.node, "/PSM1", watchdog=1.0, spin=False, polled=session.executor_time, console="auto")
        session.start()
        try:
            assert arm.wait_for_data(60.0)  # discovery: a cap, on the wall clock
            assert arm.console_namespace() == console
            arm.power_on()
            pub = arm._pubs["power_on"]
            deadline = time.monotonic() + 60.0
            while pub.get_subscription_count() == 0:  # rig sim listens on the found name
                assert time.monotonic() < deadline, f"nobody subscribes to {arm.topic['power_on']}"
                time.sleep(0.05)
            assert arm.topic["power_on"] == f"{console}/power_on"
        finally:
            arm.close()
            session.close()
