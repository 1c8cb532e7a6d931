"""Sensor messages read from their CDR bytes give what rclpy's own deserialisation gives."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from drivers.common import cdr  # noqa: E402


def _pose_msg(rng, frame: str) -> PoseStamped:
    m = PoseStamped()
    m.header.stamp.sec = int(rng.integers(0, 2**31 - 1))
    m.header.stamp.nanosec = int(rng.integers(0, 10**9))
    m.header.frame_id = frame
    v = rng.normal(size=7)
    m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) for x in v[:3])
    o = m.pose.orientation
    o.x, o.y, o.z, o.w = (float(x) for x in v[3:])
    return m


@pytest.mark.parametrize("frame", ["", "w", "world", "a_longer_frame_name", "ü"])
def test_pose_stamped_read_from_the_bytes_rclpy_writes(frame):
    rng = np.random.default_rng(len(frame))
    for _ in range(20):
        m = _pose_msg(rng, frame)
        t_ns, got_frame, v = cdr.pose_stamped(serialize_message(m))
        assert t_ns == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert got_frame == frame
        p, o = m.pose.position, m.pose.orientation
        assert v == (p.x, p.y, p.z, o.x, o.y, o.z, o.w)


@pytest.mark.parametrize("names", [(), ("outer_yaw",), ("outer_yaw", "outer_pitch", "outer_insertion", "outer_roll",
                                                           "outer_wrist_pitch", "outer_wrist_yaw", "jaw"),
                                   ("a", "bb", "ccc", "dddd", "eeeee")])
@pytest.mark.parametrize("frame", ["", "PSM1_base", "abc"])
def test_joint_state_read_from_the_bytes_rclpy_writes(names, frame):
    rng = np.random.default_rng(len(names) * 7 + len(frame))
    n = len(names)
    for k in range(6):
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = 1_795_846_937 + k, int(rng.integers(0, 10**9))
        m.header.frame_id = frame
        m.name = list(names)
        # a dVRK arm may publish fewer efforts than positions, or none
        m.position = rng.normal(size=n).tolist()
        m.velocity = rng.normal(size=n).tolist() if k % 2 == 0 else []
        m.effort = rng.normal(size=max(n - k % 3, 0)).tolist()
        got = cdr.joint_state(serialize_message(m))
        assert got == (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, frame, tuple(names),
                       tuple(m.position), tuple(m.velocity), tuple(m.effort))


def test_a_big_endian_pose():
    body = struct.pack(">iII", 12, 34, 6) + b"world\0" + b"\0" * 6 + struct.pack(">7d", *range(7))
    assert cdr.pose_stamped(b"\x00\x00\x00\x00" + body) == (12_000_000_034, "world", tuple(float(i) for i in range(7)))


def test_truncated_or_foreign_bytes_are_refused():
    rng = np.random.default_rng(1)
    pose = serialize_message(_pose_msg(rng, "world"))
    js = JointState()
    js.name, js.position = ["a", "b"], [1.0, 2.0]
    joints = serialize_message(js)
    # where each message's content ends (rclpy's buffer may carry spare bytes after it).
    # The pose: encapsulation 4, stamp and length 12, "world" and its NUL 6, padding to 8
    # counted from the encapsulation's end 6, 7 doubles 56. The joints: 4 + 12, "" 1 and
    # padding 3, the name count 4, "a" and "b" 8 each, the position count 4, 2 doubles 16
    # (already aligned), the two empty arrays' counts 8.
    ends = {cdr.pose_stamped: 4 + 12 + 6 + 6 + 56, cdr.joint_state: 4 + 12 + 4 + 4 + 16 + 4 + 16 + 8}
    assert ends[cdr.pose_stamped] == len(pose) and ends[cdr.joint_state] <= len(joints)
    for buf, read in ((pose, cdr.pose_stamped), (joints, cdr.joint_state)):
        assert read(buf[:ends[read]]) == read(buf)
        for cut in range(ends[read]):
            with pytest.raises(cdr.CdrError):
                read(buf[:cut])
    with pytest.raises(cdr.CdrError, match="no effort count"):
        cdr.joint_state(joints[:ends[cdr.joint_state] - 4])
    with pytest.raises(cdr.CdrError, match="encapsulation"):
        cdr.pose_stamped(b"\x00\x03" + pose[2:])  # a parameter-list encoding, not plain CDR
    bad = bytearray(pose)
    bad[12:16] = struct.pack("<I", 10_000)   # frame_id longer than the message
    with pytest.raises(cdr.CdrError, match="frame_id"):
        cdr.pose_stamped(bytes(bad))


@pytest.mark.ros
def test_the_arm_driver_counts_and_drops_bytes_that_are_not_a_joint_state(ros_env):
    """Over the wire in one process: a publisher of raw bytes on measured_js. A truncated
    message is counted as malformed and dropped; the next whole one is the arm's state."""
    import threading
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from drivers.arm.dvrk_arm import RosArm

    ctx = Context()
    rclpy.init(context=ctx)
    pub_node = rclpy.create_node("fake_console", context=ctx)
    sub_node = rclpy.create_node("rig_arm", context=ctx)
    arm = RosArm(sub_node, "PSM1", watchdog=30.0, spin=False, states=False, streams=("measured_js",))
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(pub_node)
    ex.add_node(sub_node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    try:
        pub = pub_node.create_publisher(JointState, "/PSM1/measured_js",
                                        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        deadline = time.monotonic() + 30  # a guard against a hang: discovery is slow on a busy machine
        while pub.get_subscription_count() == 0:
            assert time.monotonic() < deadline, "the arm's subscription never matched"
            time.sleep(0.01)
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = 1_795_846_937, 500_000_000
        m.name = ["outer_yaw", "outer_pitch", "outer_insertion"]
        m.position, m.velocity, m.effort = [0.1, -0.2, 0.12], [0.0, 0.0, 0.0], [0.3, 0.4, 1.5]
        whole = serialize_message(m)
        pub.publish(whole[:30])   # cut inside the names
        while arm.malformed == 0:
            assert time.monotonic() < deadline, "the truncated message never arrived"
            time.sleep(0.005)
        assert arm.received == 0
        pub.publish(whole)
        while arm.received == 0:
            assert time.monotonic() < deadline, "the whole message never arrived"
            time.sleep(0.005)
        js = arm.measured_js()
        assert js.t == pytest.approx(1_795_846_937.5)
        np.testing.assert_allclose(js.position, [0.1, -0.2, 0.12])
        np.testing.assert_allclose(js.effort, [0.3, 0.4, 1.5])
        assert arm.malformed == 1
    finally:
        ex.shutdown()
        arm.close()
        pub_node.destroy_node()
        sub_node.destroy_node()
        rclpy.shutdown(context=ctx)
        th.join(timeout=2)
