"""Sensor messages read from their CDR bytes give what rclpy's own deserialisation gives."""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from drivers import cdr  # noqa: E402


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
