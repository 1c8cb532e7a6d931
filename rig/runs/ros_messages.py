"""ROS 2 message definitions and their CDR encoding, for recording without rclpy.

The recorder writes ROS 2 messages into MCAP the way rosbag2 does: each schema is the
message's .msg text followed by every nested definition, separated by a line of 80 `=`
and a `MSG: pkg/Type` line, and each payload is CDR little-endian (XCDR1, the encoding
Fast DDS uses on the wire), so Foxglove, `ros2 bag` and `mcap_ros2` all decode it.

Why our own encoder: `mcap_ros2`'s dynamic encoder walks the parsed definition field by
field in pure Python (about 35 000 JointState/s on a laptop core), which leaves less than
the 10x headroom the recorder needs over 3 arms at 1 kHz. These messages have a fixed
layout once the frame id and joint names of a channel are known, so the constant bytes are
built once per channel and each sample costs one or two `struct.pack` calls. The tests
check every encoder byte for byte against `mcap_ros2`'s and decode the results with it.

Times are integer nanoseconds; a header stamp is (sec: int32, nanosec: uint32).
"""

from __future__ import annotations

import struct
from functools import lru_cache
from typing import Sequence

_SEPARATOR = "=" * 80

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_POINT = "float64 x\nfloat64 y\nfloat64 z\n"
_QUATERNION = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
_VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
_POSE = "Point position\nQuaternion orientation\n"
_WRENCH = "Vector3 force\nVector3 torque\n"


def _concatenate(top: str, *dependencies: tuple[str, str]) -> str:
    parts = [top]
    for name, text in dependencies:
        parts.append(f"{_SEPARATOR}\nMSG: {name}\n{text}")
    return "".join(parts)


JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
FLOAT64 = "std_msgs/msg/Float64"
TWIST = "geometry_msgs/msg/Twist"

#: schema name -> full concatenated ROS 2 message definition (ros2msg encoding)
DEFINITIONS: dict[str, str] = {
    JOINT_STATE: _concatenate(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
        ("std_msgs/Header", _HEADER),
        ("builtin_interfaces/Time", _TIME),
    ),
    POSE_STAMPED: _concatenate(
        "std_msgs/Header header\nPose pose\n",
        ("std_msgs/Header", _HEADER),
        ("builtin_interfaces/Time", _TIME),
        ("geometry_msgs/Pose", _POSE),
        ("geometry_msgs/Point", _POINT),
        ("geometry_msgs/Quaternion", _QUATERNION),
    ),
    WRENCH_STAMPED: _concatenate(
        "std_msgs/Header header\nWrench wrench\n",
        ("std_msgs/Header", _HEADER),
        ("builtin_interfaces/Time", _TIME),
        ("geometry_msgs/Wrench", _WRENCH),
        ("geometry_msgs/Vector3", _VECTOR3),
    ),
    FLOAT64: "float64 data\n",
    TWIST: _concatenate(
        "Vector3 linear\nVector3 angular\n",
        ("geometry_msgs/Vector3", _VECTOR3),
    ),
}

# CDR encapsulation: representation id 0x0001 = CDR little endian, options 0.
_ENCAPSULATION = b"\x00\x01\x00\x00"
_STAMP = struct.Struct("<iI")


def stamp(t_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time for a time in ns (>= 0)."""
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def _pad(offset: int, size: int) -> int:
    # CDR aligns each primitive to its size, counted from after the encapsulation header.
    return (-offset) % size


def _string(text: str, offset: int) -> tuple[bytes, int]:
    """A CDR string (uint32 length incl. NUL, bytes, NUL) starting at `offset`."""
    data = text.encode("utf-8")
    if b"\0" in data:
        raise ValueError(f"a ROS 2 string cannot contain NUL: {text!r}")
    pad = _pad(offset, 4)
    out = b"\0" * pad + struct.pack("<I", len(data) + 1) + data + b"\0"
    return out, offset + len(out)


def _sequence_layout(lengths: Sequence[int], offset: int) -> tuple[str, int]:
    """struct format for consecutive float64 sequences of the given lengths at `offset`.

    Each is a uint32 count then, if not empty, the doubles aligned to 8 (an empty sequence
    gets no padding, as in Fast CDR and mcap_ros2).
    """
    fmt = []
    for n in lengths:
        pad = _pad(offset, 4)
        fmt.append(f"{pad}xI" if pad else "I")
        offset += pad + 4
        if n:
            pad = _pad(offset, 8)
            fmt.append(f"{pad}x{n}d" if pad else f"{n}d")
            offset += pad + 8 * n
    return "".join(fmt), offset


@lru_cache(maxsize=256)
def _joint_state_layout(frame_id: str, names: tuple[str, ...], np_: int, nv: int, ne: int):
    offset = 8  # after the stamp
    const, offset = _string(frame_id, offset)
    pad = _pad(offset, 4)
    const += b"\0" * pad + struct.pack("<I", len(names))
    offset += pad + 4
    for name in names:
        piece, offset = _string(name, offset)
        const += piece
    fmt, offset = _sequence_layout((np_, nv, ne), offset)
    return _ENCAPSULATION, const, struct.Struct("<" + fmt)


def encode_joint_state(t_ns: int, frame_id: str, names: tuple[str, ...],
                       position: Sequence[float], velocity: Sequence[float],
                       effort: Sequence[float]) -> bytes:
    """sensor_msgs/msg/JointState: positions (rad or m), velocities, efforts (N m or N)."""
    np_, nv, ne = len(position), len(velocity), len(effort)
    encap, const, arrays = _joint_state_layout(frame_id, names, np_, nv, ne)
    return b"".join((encap, _STAMP.pack(*stamp(t_ns)), const,
                     arrays.pack(np_, *position, nv, *velocity, ne, *effort)))


@lru_cache(maxsize=256)
def _stamped_layout(frame_id: str, n_doubles: int):
    const, offset = _string(frame_id, 8)
    pad = _pad(offset, 8)
    return const + b"\0" * pad, struct.Struct(f"<{n_doubles}d")


def encode_pose_stamped(t_ns: int, frame_id: str, position: Sequence[float],
                        quat_xyzw: Sequence[float]) -> bytes:
    """geometry_msgs/msg/PoseStamped: position (m), orientation quaternion (x, y, z, w)."""
    const, body = _stamped_layout(frame_id, 7)
    return b"".join((_ENCAPSULATION, _STAMP.pack(*stamp(t_ns)), const,
                     body.pack(*position, *quat_xyzw)))


def encode_wrench_stamped(t_ns: int, frame_id: str, force: Sequence[float],
                          torque: Sequence[float]) -> bytes:
    """geometry_msgs/msg/WrenchStamped: force (N) and torque (N m)."""
    const, body = _stamped_layout(frame_id, 6)
    return b"".join((_ENCAPSULATION, _STAMP.pack(*stamp(t_ns)), const,
                     body.pack(*force, *torque)))


_ONE = struct.Struct("<d")
_SIX = struct.Struct("<6d")


def encode_float64(value: float) -> bytes:
    """std_msgs/msg/Float64."""
    return _ENCAPSULATION + _ONE.pack(value)


def encode_twist(linear: Sequence[float], angular: Sequence[float]) -> bytes:
    """geometry_msgs/msg/Twist: linear (m/s) and angular (rad/s) velocity."""
    return _ENCAPSULATION + _SIX.pack(*linear, *angular)
