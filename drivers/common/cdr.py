"""The CDR bytes of the rig's streams: the two a procedure receives most read, all that `rig sim` publishes written.

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

* geometry_msgs/TwistStamped, WrenchStamped: Header, then 6 float64 aligned to 8;
* std_msgs/Float64MultiArray: MultiArrayDimension[] dim (uint32 count; each a string
  label, uint32 size, uint32 stride), uint32 data_offset, float64[] data.

Malformed bytes (truncated, a bad encapsulation, a length past the end) raise
`CdrError`; the drivers count such a message and drop it. Times are integer nanoseconds.

The writers (`write_*`) give the bytes rclpy's own serialization gives (little endian),
for a raw publisher (`Publisher.publish(bytes)`): `rig sim` publishes 13 streams an arm at
up to 1 kHz, and rclpy's message objects cost more than the DDS write. A message's
layout depends only on its frame_id, names and array lengths, so it is compiled once into
a `struct.Struct` whose fixed parts are packed as constant byte strings.
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


# -- writing ---------------------------------------------------------------------------

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR little endian, no options


class _Layout:
    """A message's bytes as constant runs and value groups: c0 v0 c1 v1 ... cN, compiled to one Struct."""

    def __init__(self):
        self._consts: list[bytearray] = [bytearray(_ENCAPSULATION)]
        self._groups: list[str] = []
        self._size = _BODY

    def const(self, fmt: str, *values) -> None:
        data = struct.pack("<" + fmt, *values)
        self._consts[-1] += data
        self._size += len(data)

    def align(self, size: int) -> None:
        self.const(f"{(-(self._size - _BODY)) % size}x")

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\0"
        self.align(4)
        self.const(f"I{len(data)}s", len(data), data)

    def values(self, fmt: str, size: int) -> None:
        """A group of values packed at each write (`size` bytes: fmt's own, aligned before)."""
        self._groups.append(fmt)
        self._consts.append(bytearray())
        self._size += size

    def compile(self) -> tuple[struct.Struct, tuple[bytes, ...]]:
        fmt = "<"
        for k, group in enumerate(self._groups):
            fmt += f"{len(self._consts[k])}s{group}"
        fmt += f"{len(self._consts[-1])}s"
        return struct.Struct(fmt), tuple(bytes(c) for c in self._consts)


def _header_layout(layout: _Layout, frame_id: str) -> None:
    layout.values("iI", 8)
    layout.string(frame_id)


def _doubles(layout: _Layout, n: int) -> None:
    layout.align(4)
    layout.const("I", n)
    if n:
        layout.align(8)
        layout.values(f"{n}d", 8 * n)


_LAYOUTS: dict = {}


def _fixed(kind: str, n: int, stamp_ns: int, frame_id: str, values) -> bytes:
    """A Header then `n` float64 aligned to 8 (PoseStamped, TwistStamped, WrenchStamped)."""
    key = (kind, frame_id)
    compiled = _LAYOUTS.get(key)
    if compiled is None:
        layout = _Layout()
        _header_layout(layout, frame_id)
        layout.align(8)
        layout.values(f"{n}d", 8 * n)
        compiled = _LAYOUTS[key] = layout.compile()
    st, (c0, c1, c2) = compiled
    if len(values) != n:
        raise ValueError(f"{kind} needs {n} values, got {len(values)}")
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return st.pack(c0, sec, nanosec, c1, *values, c2)


def write_pose_stamped(stamp_ns: int, frame_id: str, pose) -> bytes:
    """geometry_msgs/PoseStamped; pose: (px, py, pz, qx, qy, qz, qw)."""
    return _fixed("pose", 7, stamp_ns, frame_id, pose)


def write_twist_stamped(stamp_ns: int, frame_id: str, twist) -> bytes:
    """geometry_msgs/TwistStamped; twist: (linear x y z, angular x y z)."""
    return _fixed("twist", 6, stamp_ns, frame_id, twist)


def write_wrench_stamped(stamp_ns: int, frame_id: str, wrench) -> bytes:
    """geometry_msgs/WrenchStamped; wrench: (force x y z, torque x y z)."""
    return _fixed("wrench", 6, stamp_ns, frame_id, wrench)


def write_joint_state(stamp_ns: int, frame_id: str, names: tuple[str, ...], position, velocity, effort) -> bytes:
    """sensor_msgs/JointState; names a tuple of str, the arrays sequences of float (any lengths)."""
    key = ("js", frame_id, names, len(position), len(velocity), len(effort))
    compiled = _LAYOUTS.get(key)
    if compiled is None:
        layout = _Layout()
        _header_layout(layout, frame_id)
        layout.align(4)
        layout.const("I", len(names))
        for name in names:
            layout.string(name)
        for n in key[3:]:
            _doubles(layout, n)
        compiled = _LAYOUTS[key] = layout.compile()
    st, consts = compiled
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    if len(consts) == 5:  # every array non-empty: the streams' case
        return st.pack(consts[0], sec, nanosec, consts[1], *position, consts[2], *velocity, consts[3], *effort,
                       consts[4])
    args = [consts[0], sec, nanosec, consts[1]]
    k = 2
    for values in (position, velocity, effort):
        if len(values):
            args.extend(values)
            args.append(consts[k])
            k += 1
    return st.pack(*args)


def write_float64_multi_array(dims: tuple[tuple[str, int, int], ...], data, data_offset: int = 0) -> bytes:
    """std_msgs/Float64MultiArray; dims: a tuple of (label, size, stride), one per dimension; data: floats."""
    key = ("mat", dims, data_offset, len(data))
    compiled = _LAYOUTS.get(key)
    if compiled is None:
        layout = _Layout()
        layout.const("I", len(dims))
        for label, size, stride in dims:
            layout.string(label)
            layout.align(4)
            layout.const("II", size, stride)
        layout.align(4)
        layout.const("I", data_offset)
        _doubles(layout, len(data))
        compiled = _LAYOUTS[key] = layout.compile()
    st, consts = compiled
    return st.pack(consts[0], *data, consts[1]) if len(data) else st.pack(consts[0])
