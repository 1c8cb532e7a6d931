"""Reading the two sensor messages a procedure receives most straight from their CDR bytes.

A procedure on the lab's rig receives 11 mocap bodies at 120 Hz and 2-3 arms'
measured_js at 500 Hz: 2 300-2 800 messages a second on one executor thread. rclpy turns
each into Python message objects field by field (40 us for a PoseStamped, 29 us for a
7-joint JointState on this machine); on a process that shares its core with others, the
thread then falls behind the streams, its DDS history (KEEP_LAST) fills, and the oldest
samples are dropped per topic, so the bodies of one mocap frame are lost at different
stamps. A raw subscription (`create_subscription(..., raw=True)`) hands over the
serialized bytes, and these fixed layouts are read with `struct` in about 1-3 us.

The bytes are what the RMW hands to a raw subscription: a 4-byte encapsulation header
(0x00 0x01 for CDR little endian, 0x00 0x00 for big endian; two option bytes) followed by
the XCDR1 body, whose alignment is counted from the end of that header. The layouts:

* std_msgs/Header: int32 sec, uint32 nanosec, string frame_id (uint32 length with the
  terminating NUL, the bytes, the NUL);
* geometry_msgs/PoseStamped: Header, then 7 float64 (position x y z, orientation x y z w),
  aligned to 8;
* sensor_msgs/JointState: Header, string[] name (uint32 count, then strings each aligned
  to 4), float64[] position, velocity, effort (uint32 count, aligned to 4; the doubles
  aligned to 8).

Malformed bytes (truncated, a bad encapsulation, a length past the end) raise
`CdrError`; the drivers count such a message and drop it. Times are integer nanoseconds.
"""

from __future__ import annotations

import struct

_ENDIAN = {b"\x00\x01": "<", b"\x00\x00": ">"}
_BODY = 4  # the encapsulation header's size: CDR alignment counts from here


class CdrError(ValueError):
    """Bytes that are not the CDR of the message they were read as."""


def _endian(buf: bytes) -> str:
    if len(buf) < _BODY:
        raise CdrError(f"{len(buf)} bytes: shorter than the CDR encapsulation header")
    e = _ENDIAN.get(bytes(buf[:2]))
    if e is None:
        raise CdrError(f"encapsulation {bytes(buf[:2]).hex()}: not plain CDR (0001 little or 0000 big endian)")
    return e


def _align(offset: int, size: int) -> int:
    return offset + (-(offset - _BODY)) % size


def _header(buf: bytes, e: str) -> tuple[int, str, int]:
    """(stamp ns, frame_id, offset after the header)."""
    if len(buf) < _BODY + 12:
        raise CdrError(f"{len(buf)} bytes: too short for a std_msgs/Header")
    sec, nanosec, n = struct.unpack_from(e + "iII", buf, _BODY)
    start = _BODY + 12
    end = start + n
    if n == 0 or end > len(buf):
        raise CdrError(f"frame_id of {n} bytes at offset {start} runs past the message's {len(buf)} bytes")
    frame = bytes(buf[start:end - 1]).decode("utf-8", "replace")
    return sec * 1_000_000_000 + nanosec, frame, end


def pose_stamped(buf: bytes) -> tuple[int, str, tuple[float, ...]]:
    """(stamp ns, frame_id, (px, py, pz, qx, qy, qz, qw)) of a geometry_msgs/PoseStamped."""
    e = _endian(buf)
    t_ns, frame, off = _header(buf, e)
    off = _align(off, 8)
    if off + 56 > len(buf):
        raise CdrError(f"{len(buf)} bytes: the pose (56 bytes at offset {off}) runs past the end")
    return t_ns, frame, struct.unpack_from(e + "7d", buf, off)


def joint_state(buf: bytes) -> tuple[int, str, tuple[str, ...], tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """(stamp ns, frame_id, names, position, velocity, effort) of a sensor_msgs/JointState."""
    e = _endian(buf)
    t_ns, frame, off = _header(buf, e)
    size = len(buf)
    off = _align(off, 4)
    if off + 4 > size:
        raise CdrError(f"{size} bytes: no name count at offset {off}")
    (count,) = struct.unpack_from(e + "I", buf, off)
    off += 4
    names = []
    for _ in range(count):
        off = _align(off, 4)
        if off + 4 > size:
            raise CdrError(f"{size} bytes: name {len(names)} runs past the end")
        (n,) = struct.unpack_from(e + "I", buf, off)
        off += 4
        if n == 0 or off + n > size:
            raise CdrError(f"name {len(names)} of {n} bytes at offset {off} runs past the message's {size} bytes")
        names.append(bytes(buf[off:off + n - 1]).decode("utf-8", "replace"))
        off += n
    arrays = []
    for field in ("position", "velocity", "effort"):
        off = _align(off, 4)
        if off + 4 > size:
            raise CdrError(f"{size} bytes: no {field} count at offset {off}")
        (n,) = struct.unpack_from(e + "I", buf, off)
        off += 4
        if n:
            off = _align(off, 8)
            if off + 8 * n > size:
                raise CdrError(f"{field} of {n} doubles at offset {off} runs past the message's {size} bytes")
            arrays.append(struct.unpack_from(f"{e}{n}d", buf, off))
            off += 8 * n
        else:
            arrays.append(())
    return t_ns, frame, tuple(names), arrays[0], arrays[1], arrays[2]
