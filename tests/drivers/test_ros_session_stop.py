"""A procedure's ROS session stops spinning before any driver destroys its endpoints:
destroyed under a spinning executor, an endpoint takes the process down (SIGSEGV), which
is what a dying `rig sim` did to a procedure (issue 37)."""

from __future__ import annotations

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from drivers.common.ros_session import RosSession  # noqa: E402
from rig.devices.factory import _once_stopped  # noqa: E402

pytestmark = pytest.mark.ros


class _Session:
    def __init__(self, executor, stopped):
        self.executor, self.stopped = executor, stopped


@pytest.mark.parametrize("executor, stopped, closes", [
    (None, False, True),        # never started: nothing spins
    (object(), False, False),   # spinning (or stuck): the endpoints are left alone
    (object(), True, True),     # stopped: safe to destroy
])
def test_a_driver_closes_only_once_nothing_spins_its_node(executor, stopped, closes):
    closed = []
    _once_stopped(_Session(executor, stopped), lambda: closed.append(1))()
    assert closed == ([1] if closes else [])


@pytest.mark.parametrize("kind", ["events", "single"])
def test_stop_ends_the_spin_thread_then_endpoints_can_go(ros_env, kind):
    from std_msgs.msg import Float64

    session = RosSession("stop_test", executor=kind)
    sub = session.node.create_subscription(Float64, "/stop_test/x", lambda m: None, 10)
    pub = session.node.create_publisher(Float64, "/stop_test/x", 10)
    session.start()
    for _ in range(20):
        pub.publish(Float64(data=1.0))
    assert session.stop() is True and session.stopped
    assert not session._thread.is_alive()
    assert session.stop() is True  # idempotent
    session.node.destroy_subscription(sub)
    session.node.destroy_publisher(pub)
    session.close()
    # parked until the process ends, not deleted (drivers/common/ros_exit.py)
    from drivers.common import ros_exit

    assert ros_exit._parked[-1] == ((session.control, session.node), session.context)
