"""The simulated operator's client over ROS 2 (drivers.operator.driver.RosOperator): a request
that waits for `rig sim`'s person ends at once on the rig's device fault (`watch`), not
only on the reply or the operator's timeout."""

from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from drivers.operator.driver import REQUEST_TOPIC, OperatorError, RosOperator  # noqa: E402
from drivers.common.ros_session import RosSession  # noqa: E402

pytestmark = pytest.mark.ros


class _Gone(Exception):
    pass


@pytest.fixture
def silent_person(ros_env):
    """A session with somebody listening on the request topic who never answers (a
    rig sim whose world has stopped)."""
    from std_msgs.msg import String

    session = RosSession("operator_test")
    heard = []
    session.control.create_subscription(String, REQUEST_TOPIC, lambda m: heard.append(m.data), 10)
    operator = RosOperator(session.control, timeout=30.0)
    session.start()
    yield operator, heard
    session.close()


def test_a_device_fault_ends_the_wait_for_a_reply(silent_person):
    operator, heard = silent_person
    calls = []

    def watch():
        calls.append(time.monotonic())
        if len(calls) >= 3:
            raise _Gone("PSM1: stale stream")

    operator.watch = watch
    with pytest.raises(_Gone):  # not OperatorError: the wait ended on the fault, not the timeout
        operator.confirm("hold on")
    assert heard and '"confirm"' in heard[0]
    assert len(calls) == 3


def test_without_a_watch_the_wait_ends_on_the_timeout(silent_person):
    operator, _ = silent_person
    operator.timeout = 0.5
    with pytest.raises(OperatorError, match="did not answer 'confirm' within 0.5 s"):
        operator.confirm("hold on")
