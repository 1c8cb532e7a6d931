"""The stream messages `rig sim` writes as CDR bytes are what rclpy's own serialization gives.

Byte for byte, but for what rclpy leaves uninitialized: the alignment padding (its
serializer skips those bytes, so they hold whatever the buffer held) and a tail past the
message (its buffer is sized by an estimate). Every byte that differs is shown to be one
that rclpy's deserializer ignores, and rclpy's bytes cut to ours read as the whole message.
"""

from __future__ import annotations

import numpy as np
import pytest

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from drivers.common import cdr

FRAMES = ["", "w", "ab", "abc", "PSM1_base", "a_longer_frame_name", "ü"]
#: stamps in ns: zero, under a second, a wall-clock stamp, the largest int32 second, a negative one
STAMPS = [0, 999_999_999, 1_795_846_937_123_456_789, (2**31 - 1) * 1_000_000_000 + 5, -1_500_000_000]


def assert_rclpys(ours: bytes, msg) -> None:
    """`ours` are rclpy's bytes for `msg` wherever a byte carries the message."""
    theirs = serialize_message(msg)
    kind = type(msg)
    assert deserialize_message(ours, kind) == msg
    assert len(ours) <= len(theirs)
    assert deserialize_message(theirs[:len(ours)], kind) == msg
    for i in range(len(ours)):
        if ours[i] != theirs[i]:
            flipped = ours[:i] + bytes([ours[i] ^ 0xFF]) + ours[i + 1:]
            assert deserialize_message(flipped, kind) == msg, f"byte {i} differs from rclpy's and carries the message"


def _stamped(m, stamp_ns: int, frame: str):
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.header.frame_id = frame
    return m


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("stamp_ns", STAMPS)
def test_pose_twist_and_wrench_bytes_are_rclpys(frame, stamp_ns):
    rng = np.random.default_rng(len(frame) + stamp_ns % 97)
    v = rng.normal(size=7).tolist()
    m = _stamped(PoseStamped(), stamp_ns, frame)
    (m.pose.position.x, m.pose.position.y, m.pose.position.z,
     m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w) = v
    assert_rclpys(cdr.write_pose_stamped(stamp_ns, frame, v), m)
    t = _stamped(TwistStamped(), stamp_ns, frame)
    t.twist.linear.x, t.twist.linear.y, t.twist.linear.z = v[:3]
    t.twist.angular.x, t.twist.angular.y, t.twist.angular.z = v[3:6]
    assert_rclpys(cdr.write_twist_stamped(stamp_ns, frame, v[:6]), t)
    w = _stamped(WrenchStamped(), stamp_ns, frame)
    w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = v[:3]
    w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = v[3:6]
    assert_rclpys(cdr.write_wrench_stamped(stamp_ns, frame, v[:6]), w)


@pytest.mark.parametrize("names", [(), ("jaw",), ("a", "bb", "ccc", "dddd", "eeeee"),
                                   ("outer_yaw", "outer_pitch", "outer_insertion", "outer_roll",
                                    "outer_wrist_pitch", "outer_wrist_yaw")])
@pytest.mark.parametrize("frame", FRAMES)
def test_joint_state_bytes_are_rclpys(names, frame):
    rng = np.random.default_rng(len(names) * 7 + len(frame))
    n = len(names)
    for k, stamp_ns in enumerate(STAMPS):
        # arrays of the names' length, shorter, or empty (a dVRK arm may publish no effort)
        lengths = [(n, n, n), (n, 0, n), (0, 0, 0), (n, n, max(n - 1, 0)), (1, 0, 2)][k]
        arrays = [rng.normal(size=m).tolist() for m in lengths]
        msg = _stamped(JointState(), stamp_ns, frame)
        msg.name = list(names)
        msg.position, msg.velocity, msg.effort = arrays
        assert_rclpys(cdr.write_joint_state(stamp_ns, frame, names, *arrays), msg)
        # and the reader gives the message back
        assert cdr.joint_state(cdr.write_joint_state(stamp_ns, frame, names, *arrays)) == (
            stamp_ns, frame, tuple(names), *(tuple(a) for a in arrays))


@pytest.mark.parametrize("dims", [(), (("rows", 6, 36), ("columns", 6, 6)), (("x", 3, 3),),
                                  (("", 0, 0), ("longer label", 2**32 - 1, 7))])
@pytest.mark.parametrize("n", [0, 1, 5, 36])
@pytest.mark.parametrize("data_offset", [0, 3])
def test_float64_multi_array_bytes_are_rclpys(dims, n, data_offset):
    data = np.random.default_rng(n).normal(size=n).tolist()
    m = Float64MultiArray()
    m.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride) for label, size, stride in dims]
    m.layout.data_offset = data_offset
    m.data = data
    assert_rclpys(cdr.write_float64_multi_array(dims, data, data_offset), m)


def test_numpy_values_write_the_same_bytes_as_floats():
    q = np.array([0.1, -0.2, 0.3])
    assert cdr.write_joint_state(5, "f", ("a", "b", "c"), q, q, q) == cdr.write_joint_state(
        5, "f", ("a", "b", "c"), q.tolist(), q.tolist(), q.tolist())


def test_a_pose_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="pose needs 7 values, got 6"):
        cdr.write_pose_stamped(0, "w", [0.0] * 6)
