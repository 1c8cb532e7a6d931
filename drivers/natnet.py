"""OptiTrack Motive's NatNet stream (bitstream 3.x and 4.x): wire protocol and tracker driver.

The protocol is written out in `drivers/NATNET_PROTOCOL.md`; this module follows it byte
for byte. Layers, bottom up:

- message framing (`pack_message`, `split_message`) and the payload codecs of the
  messages a rigid-body client needs: NAT_CONNECT, NAT_SERVERINFO, NAT_MODELDEF (data
  descriptions: rigid bodies and their markers, marker sets; the other kinds are skipped)
  and NAT_FRAMEOFDATA (every section is parsed, so a frame decodes only if its byte count
  adds up exactly: a layout of the wrong version or a cut datagram cannot pass as data);
- `HostClockMap`: Motive's high-resolution clock (ticks) onto this host's clock, by the
  lower envelope of (receipt - transmit) with a line through block minima for drift;
- `UdpTransport`: the two NatNet channels on UDP (one client socket for commands and
  unicast frames, plus a multicast socket when the stream is multicast);
- `NatNetTracker`: the host driver. It is given a transport, runs a reader thread and
  implements `drivers.interfaces.Tracker`. Rigid bodies are named by the model
  definitions; a body whose tracking-valid flag is cleared is None in its frame.

The fake Motive server that speaks this protocol from the simulated rig is
`drivers.natnet_server.FakeMotive`.

Why our own decoder and not the `natnet` package on PyPI (0.3.0): see NATNET_PROTOCOL.md,
"Why not a maintained client" (it misreads NatNet 4.1 frame suffixes, cannot be given a
transport, prints instead of counting bad packets and binds the wildcard address).

Units: positions m, times s on the host clock (`time.time()`, as ROS stamps) unless a
name ends in `_ticks` (Motive's clock) ; quaternions (x, y, z, w) as on the wire.
"""

from __future__ import annotations

import ipaddress
import math
import select
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from drivers.interfaces import Pose, TrackerFrame
from drivers.mocap import MocapStaleError
from drivers.quaternion import quat_xyzw_to_matrix
from rig.faults import DeviceFault, rate_of, silence_text, starved_text

# --------------------------------------------------------------------------- message ids

NAT_CONNECT = 0
NAT_SERVERINFO = 1
NAT_REQUEST = 2
NAT_RESPONSE = 3
NAT_REQUEST_MODELDEF = 4
NAT_MODELDEF = 5
NAT_REQUEST_FRAMEOFDATA = 6
NAT_FRAMEOFDATA = 7
NAT_MESSAGESTRING = 8
NAT_DISCONNECT = 9
NAT_KEEPALIVE = 10
NAT_UNRECOGNIZED_REQUEST = 100

MESSAGE_NAMES = {NAT_CONNECT: "NAT_CONNECT", NAT_SERVERINFO: "NAT_SERVERINFO", NAT_REQUEST: "NAT_REQUEST",
                 NAT_RESPONSE: "NAT_RESPONSE", NAT_REQUEST_MODELDEF: "NAT_REQUEST_MODELDEF",
                 NAT_MODELDEF: "NAT_MODELDEF", NAT_REQUEST_FRAMEOFDATA: "NAT_REQUEST_FRAMEOFDATA",
                 NAT_FRAMEOFDATA: "NAT_FRAMEOFDATA", NAT_MESSAGESTRING: "NAT_MESSAGESTRING",
                 NAT_DISCONNECT: "NAT_DISCONNECT", NAT_KEEPALIVE: "NAT_KEEPALIVE",
                 NAT_UNRECOGNIZED_REQUEST: "NAT_UNRECOGNIZED_REQUEST"}

# data description kinds in NAT_MODELDEF
DESC_MARKERSET = 0
DESC_RIGIDBODY = 1
DESC_SKELETON = 2
DESC_FORCEPLATE = 3
DESC_DEVICE = 4
DESC_CAMERA = 5
DESC_ASSET = 6

RB_TRACKING_VALID = 0x01          # rigid body params bit 0
MARKER_OCCLUDED = 0x01            # labelled marker params
MARKER_POINT_CLOUD_SOLVED = 0x02
MARKER_MODEL_SOLVED = 0x04
MARKER_HAS_MODEL = 0x08
FRAME_RECORDING = 0x01            # frame suffix params
FRAME_MODELS_CHANGED = 0x02

HEADER = struct.Struct("<HH")     # message id, payload bytes
NAME_FIELD = 256                  # sSender's fixed name field
SENDER = struct.Struct("<256s4B4B")
SERVER_EXTRA = struct.Struct("<QH?4B")  # clock Hz, data port, multicast, group address
CONNECT_OPTIONS = struct.Struct("<B4B")  # subscribed data only, requested bitstream version
MAX_PAYLOAD = 0xFFFF              # a u16 byte count
DEFAULT_MULTICAST_GROUP = "239.255.42.99"

_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")
_I16 = struct.Struct("<h")
_F32 = struct.Struct("<f")
_V3 = struct.Struct("<3f")
_RB = struct.Struct("<i3f4ffh")       # id, position, quaternion xyzw, mean error, params
_LM = struct.Struct("<i3ffhf")        # id, position, size, params, residual (3.0+)
_SUFFIX3 = struct.Struct("<IIdQQQ")   # timecode, subframe, timestamp, mid-exposure, received, transmit
_PRECISION = struct.Struct("<II")     # 4.1+: precision timestamp s, fractional s
_ASSET_RB = _RB                       # asset bones have the rigid-body layout
_ASSET_MK = struct.Struct("<i3ffhf")  # id, position, size, params, residual

Version = tuple  # (major, minor, build, revision)


def supported(version: Sequence[int]) -> bool:
    """Bitstreams this module decodes: 3.0-3.1 (Motive 2.x) and 4.x (Motive 3.x)."""
    return len(version) >= 2 and (version[0] == 4 or (version[0] == 3 and version[1] <= 1))


def version_text(version: Sequence[int]) -> str:
    return ".".join(str(int(v)) for v in version[:2])


def _sizes(version: Sequence[int]) -> bool:
    """NatNet 4.1 and later put a byte count after each section's count."""
    return tuple(version[:2]) >= (4, 1)


# --------------------------------------------------------------------------- errors

class NatNetError(DeviceFault):
    """Anything wrong with the NatNet stream that a procedure should stop on (one line)."""


class NatNetConnectError(NatNetError):
    """No server answered, or it does not have the rigid bodies asked for."""


class NatNetVersionError(NatNetError):
    """The server streams a bitstream version this driver does not decode."""


class NatNetDecodeError(ValueError):
    """A packet that does not decode; `kind` is "truncated", "trailing" or "malformed"."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


# --------------------------------------------------------------------------- framing

def pack_message(message_id: int, payload: bytes = b"") -> bytes:
    """One datagram: id u16 | payload byte count u16 | payload (little-endian)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds NatNet's u16 byte count")
    return HEADER.pack(message_id, len(payload)) + payload


def split_message(datagram: bytes) -> tuple[int, bytes]:
    """(message id, payload) of a datagram whose byte count must match its length."""
    if len(datagram) < HEADER.size:
        raise NatNetDecodeError("truncated", f"datagram of {len(datagram)} bytes has no 4-byte header")
    message_id, n = HEADER.unpack_from(datagram)
    have = len(datagram) - HEADER.size
    if have < n:
        raise NatNetDecodeError("truncated", f"{MESSAGE_NAMES.get(message_id, message_id)} declares {n} "
                                             f"payload bytes, the datagram holds {have}")
    if have > n:
        raise NatNetDecodeError("trailing", f"{MESSAGE_NAMES.get(message_id, message_id)} declares {n} "
                                            f"payload bytes, the datagram holds {have}")
    return message_id, bytes(datagram[HEADER.size:])


class _Reader:
    """Bounds-checked little-endian reads over a payload (every short read is 'truncated')."""

    __slots__ = ("data", "pos", "what")

    def __init__(self, data: bytes, what: str):
        self.data = memoryview(data)
        self.pos = 0
        self.what = what

    def need(self, n: int, field_: str) -> None:
        if self.pos + n > len(self.data):
            raise NatNetDecodeError("truncated", f"{self.what}: {field_} needs {n} bytes at byte {self.pos}, "
                                                 f"{len(self.data) - self.pos} left")

    def unpack(self, st: struct.Struct, field_: str) -> tuple:
        self.need(st.size, field_)
        out = st.unpack_from(self.data, self.pos)
        self.pos += st.size
        return out

    def i32(self, field_: str) -> int:
        return self.unpack(_I32, field_)[0]

    def count(self, field_: str, item_bytes: int) -> int:
        """A non-negative count whose items (at least `item_bytes` each) fit in what is left."""
        n = self.i32(field_)
        if n < 0 or n * item_bytes > len(self.data) - self.pos:
            raise NatNetDecodeError("truncated" if n >= 0 else "malformed",
                                    f"{self.what}: {field_} = {n} does not fit in the "
                                    f"{len(self.data) - self.pos} bytes left at byte {self.pos}")
        return n

    def floats(self, n: int, field_: str) -> tuple:
        return self.unpack(struct.Struct(f"<{n}f"), field_) if n else ()

    def cstring(self, field_: str) -> str:
        end = bytes(self.data[self.pos:]).find(b"\0")
        if end < 0:
            raise NatNetDecodeError("truncated", f"{self.what}: {field_} has no terminating NUL")
        text = bytes(self.data[self.pos:self.pos + end]).decode("utf-8", errors="replace")
        self.pos += end + 1
        return text

    def skip(self, n: int, field_: str) -> None:
        self.need(n, field_)
        self.pos += n

    def done(self) -> None:
        if self.pos != len(self.data):
            raise NatNetDecodeError("trailing", f"{self.what}: {len(self.data) - self.pos} bytes left over "
                                                f"after byte {self.pos}")


def _cstr(text: str) -> bytes:
    raw = text.encode("utf-8")
    if b"\0" in raw:
        raise ValueError(f"name {text!r} contains a NUL")
    return raw + b"\0"


# --------------------------------------------------------------------------- handshake

@dataclass(frozen=True)
class ConnectRequest:
    """A client's NAT_CONNECT: its name and versions, and the bitstream it asks for (0.0: the server's)."""

    name: str = "dvrk-rig"
    version: Version = (1, 0, 0, 0)
    natnet_version: Version = (4, 1, 0, 0)
    bitstream: Version = (0, 0, 0, 0)
    subscribed_only: bool = False


def encode_connect(req: ConnectRequest = ConnectRequest()) -> bytes:
    """NAT_CONNECT as NatNet 4.x clients send it: sSender (264 B) + connection options (5 B)."""
    name = req.name.encode("utf-8")[:NAME_FIELD - 1]
    payload = SENDER.pack(name, *req.version, *req.natnet_version) + CONNECT_OPTIONS.pack(
        int(req.subscribed_only), *req.bitstream)
    return pack_message(NAT_CONNECT, payload)


def decode_connect(payload: bytes) -> ConnectRequest:
    """Any client's NAT_CONNECT: the 269-byte form, the SDK Python sample's 271-byte 'Ping'
    block (same offsets) or a bare 'Ping' string (older clients): what is absent is zero."""
    if len(payload) < SENDER.size:
        return ConnectRequest(name=payload.split(b"\0", 1)[0].decode("utf-8", "replace"),
                              version=(0, 0, 0, 0), natnet_version=(0, 0, 0, 0))
    raw, *v = SENDER.unpack_from(payload)
    opts = (0, 0, 0, 0, 0)
    if len(payload) >= SENDER.size + CONNECT_OPTIONS.size:
        opts = CONNECT_OPTIONS.unpack_from(payload, SENDER.size)
    return ConnectRequest(raw.split(b"\0", 1)[0].decode("utf-8", "replace"), tuple(v[:4]), tuple(v[4:]),
                          tuple(opts[1:]), bool(opts[0]))


@dataclass(frozen=True)
class ServerInfo:
    """NAT_SERVERINFO (sSender_Server): who streams, which bitstream, its clock and data channel.

    clock_hz: ticks per second of the stamps in frames (0 if the server did not say);
    multicast_group: dotted address ("" in unicast)."""

    app_name: str
    app_version: Version
    natnet_version: Version
    clock_hz: int = 0
    data_port: int = 0
    multicast: bool = False
    multicast_group: str = ""


def encode_server_info(info: ServerInfo) -> bytes:
    group = socket.inet_aton(info.multicast_group) if info.multicast_group else b"\0\0\0\0"
    payload = SENDER.pack(info.app_name.encode("utf-8")[:NAME_FIELD - 1], *info.app_version,
                          *info.natnet_version) + SERVER_EXTRA.pack(info.clock_hz, info.data_port,
                                                                     info.multicast, *group)
    return pack_message(NAT_SERVERINFO, payload)


def decode_server_info(payload: bytes) -> ServerInfo:
    """The 279-byte sSender_Server, or a bare 264-byte sSender (no clock nor data port)."""
    if len(payload) < SENDER.size:
        raise NatNetDecodeError("truncated", f"NAT_SERVERINFO of {len(payload)} bytes; needs at least {SENDER.size}")
    raw, *v = SENDER.unpack_from(payload)
    info = dict(app_name=raw.split(b"\0", 1)[0].decode("utf-8", "replace"), app_version=tuple(v[:4]),
                natnet_version=tuple(v[4:]))
    if len(payload) >= SENDER.size + SERVER_EXTRA.size:
        hz, port, multicast, *g = SERVER_EXTRA.unpack_from(payload, SENDER.size)
        info.update(clock_hz=hz, data_port=port, multicast=multicast,
                    multicast_group=socket.inet_ntoa(bytes(g)) if multicast else "")
    return ServerInfo(**info)


# --------------------------------------------------------------------------- model definitions

@dataclass(frozen=True)
class RigidBodyDescription:
    """A rigid body as Motive defines it: streaming id, name, marker offsets (n, 3) m from the
    pivot, marker names (4.0+; "Marker<k>" before), active labels (0 for passive markers)."""

    name: str
    id: int
    markers: np.ndarray
    marker_names: tuple[str, ...] = ()
    parent_id: int = -1
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    active_labels: tuple[int, ...] = ()

    def marker_label(self, k: int) -> str:
        """The k-th (0-based) marker's name."""
        return self.marker_names[k] if k < len(self.marker_names) and self.marker_names[k] else f"Marker{k + 1}"


@dataclass(frozen=True)
class ModelDefinitions:
    """NAT_MODELDEF: rigid bodies, marker sets (name -> marker names), and the kinds skipped."""

    rigid_bodies: tuple[RigidBodyDescription, ...] = ()
    marker_sets: dict[str, tuple[str, ...]] = field(default_factory=dict)
    skipped: dict[int, int] = field(default_factory=dict)  # description kind -> count


def _rigid_body_description(rb: RigidBodyDescription, version) -> bytes:
    out = bytearray(_cstr(rb.name))
    out += struct.pack("<ii3f", rb.id, rb.parent_id, *rb.offset)
    if tuple(version[:2]) >= (4, 2):
        out += struct.pack("<4f", *rb.orientation)
    if version[0] >= 3:
        m = np.asarray(rb.markers, float).reshape(-1, 3)
        out += _I32.pack(len(m))
        out += struct.pack(f"<{3 * len(m)}f", *m.ravel()) if len(m) else b""
        labels = rb.active_labels or (0,) * len(m)
        out += struct.pack(f"<{len(m)}i", *labels) if len(m) else b""
        if version[0] >= 4:
            for k in range(len(m)):
                out += _cstr(rb.marker_label(k))
    return bytes(out)


def encode_modeldef(defs: ModelDefinitions, version: Version) -> bytes:
    """NAT_MODELDEF in `version`'s layout: marker sets first, then rigid bodies (as Motive lists them)."""
    items: list[tuple[int, bytes]] = []
    for name, markers in defs.marker_sets.items():
        items.append((DESC_MARKERSET, _cstr(name) + _I32.pack(len(markers)) + b"".join(_cstr(m) for m in markers)))
    for rb in defs.rigid_bodies:
        items.append((DESC_RIGIDBODY, _rigid_body_description(rb, version)))
    out = bytearray(_I32.pack(len(items)))
    for kind, body in items:
        out += _I32.pack(kind)
        if _sizes(version):
            out += _I32.pack(len(body))
        out += body
    return pack_message(NAT_MODELDEF, bytes(out))


def _read_rigid_body_description(r: _Reader, version) -> RigidBodyDescription:
    name = r.cstring("rigid body name")
    rb_id, parent = r.unpack(struct.Struct("<ii"), "rigid body id")
    offset = r.unpack(_V3, "rigid body offset")
    orientation = (0.0, 0.0, 0.0, 1.0)
    if tuple(version[:2]) >= (4, 2):
        orientation = r.unpack(struct.Struct("<4f"), "rigid body orientation")
    markers = np.zeros((0, 3))
    labels: tuple = ()
    names: tuple = ()
    if version[0] >= 3:
        n = r.count("rigid body marker count", 16)
        markers = np.array(r.floats(3 * n, "marker offsets"), float).reshape(n, 3)
        labels = r.unpack(struct.Struct(f"<{n}i"), "marker labels") if n else ()
        if version[0] >= 4:
            names = tuple(r.cstring("marker name") for _ in range(n))
    return RigidBodyDescription(name, rb_id, markers, names, parent, tuple(offset), tuple(orientation), tuple(labels))


def _skip_description(r: _Reader, kind: int, version) -> None:
    """Parse past a description this driver does not use (needed before 4.1, which has no byte counts)."""
    if kind == DESC_SKELETON:
        r.cstring("skeleton name")
        r.i32("skeleton id")
        for _ in range(r.count("skeleton bone count", 20)):
            _read_rigid_body_description(r, version)
    elif kind == DESC_FORCEPLATE:
        r.i32("force plate id")
        r.cstring("force plate serial")
        r.skip(4 * (2 + 3 + 144 + 12), "force plate geometry")
        r.skip(8, "force plate kinds")
        for _ in range(r.count("force plate channel count", 1)):
            r.cstring("channel name")
    elif kind == DESC_DEVICE:
        r.i32("device id")
        r.cstring("device name")
        r.cstring("device serial")
        r.skip(8, "device kinds")
        for _ in range(r.count("device channel count", 1)):
            r.cstring("channel name")
    elif kind == DESC_CAMERA:
        r.cstring("camera name")
        r.skip(28, "camera pose")
    else:
        raise NatNetDecodeError("malformed", f"NAT_MODELDEF: description kind {kind} cannot be skipped "
                                             f"without the byte counts of NatNet 4.1")


def decode_modeldef(payload: bytes, version: Version) -> ModelDefinitions:
    r = _Reader(payload, f"NAT_MODELDEF ({version_text(version)})")
    bodies, sets, skipped = [], {}, {}
    for _ in range(r.count("description count", 4)):
        kind = r.i32("description kind")
        size = r.i32("description byte count") if _sizes(version) else None
        start = r.pos
        if kind == DESC_RIGIDBODY:
            bodies.append(_read_rigid_body_description(r, version))
        elif kind == DESC_MARKERSET:
            name = r.cstring("marker set name")
            sets[name] = tuple(r.cstring("marker name") for _ in range(r.count("marker set marker count", 1)))
        elif size is not None:
            r.skip(size, f"description of kind {kind}")
            skipped[kind] = skipped.get(kind, 0) + 1
        else:
            _skip_description(r, kind, version)
            skipped[kind] = skipped.get(kind, 0) + 1
        if size is not None and r.pos - start != size:
            raise NatNetDecodeError("malformed", f"NAT_MODELDEF: a description of kind {kind} declares {size} "
                                                 f"bytes and takes {r.pos - start}")
    r.done()
    return ModelDefinitions(tuple(bodies), sets, skipped)


# --------------------------------------------------------------------------- frames of data

@dataclass(frozen=True)
class RigidBodyData:
    """One rigid body in a frame: streaming id, position (m), quaternion (x, y, z, w), mean
    marker error (m), params (bit 0: tracking valid)."""

    id: int
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    mean_error: float = 0.0
    params: int = RB_TRACKING_VALID

    @property
    def tracking_valid(self) -> bool:
        return bool(self.params & RB_TRACKING_VALID)


@dataclass(frozen=True)
class LabeledMarker:
    """A labelled marker: id = model id << 16 | marker id (1-based within its rigid body),
    position (m), size (m), params (bit 0 occluded ...), residual (m)."""

    id: int
    position: tuple[float, float, float]
    size: float = 0.0
    params: int = 0
    residual: float = 0.0

    @property
    def model_id(self) -> int:
        return (self.id >> 16) & 0xFFFF

    @property
    def marker_id(self) -> int:
        return self.id & 0xFFFF


@dataclass(frozen=True)
class FrameOfData:
    """NAT_FRAMEOFDATA: what a rigid-body client keeps of it (other sections are parsed and
    counted). Stamps in Motive's clock ticks (ServerInfo.clock_hz); timestamp in s since
    Motive's start; params bit 0 recording, bit 1 tracked models changed."""

    frame_number: int
    rigid_bodies: tuple[RigidBodyData, ...] = ()
    labeled_markers: tuple[LabeledMarker, ...] = ()
    timestamp: float = 0.0
    mid_exposure_ticks: int = 0
    data_received_ticks: int = 0
    transmit_ticks: int = 0
    timecode: int = 0
    timecode_sub: int = 0
    precision_s: int = 0
    precision_frac: int = 0
    params: int = 0
    marker_sets: dict[str, int] = field(default_factory=dict)  # name -> marker count
    other_markers: int = 0
    skeletons: int = 0
    assets: int = 0
    force_plates: int = 0
    devices: int = 0

    @property
    def models_changed(self) -> bool:
        return bool(self.params & FRAME_MODELS_CHANGED)


def _section(out: bytearray, version, count: int, body: bytes) -> None:
    out += _I32.pack(count)
    if _sizes(version):
        out += _I32.pack(len(body))
    out += body


def encode_frame(frame: FrameOfData, version: Version) -> bytes:
    """NAT_FRAMEOFDATA in `version`'s layout (marker sets, other markers, skeletons, assets,
    force plates and devices empty), ending with the 4-byte end-of-data tag."""
    out = bytearray(_I32.pack(frame.frame_number))
    _section(out, version, 0, b"")  # marker sets
    _section(out, version, 0, b"")  # legacy other markers
    _section(out, version, len(frame.rigid_bodies),
             b"".join(_RB.pack(b.id, *b.position, *b.quaternion, b.mean_error, b.params) for b in frame.rigid_bodies))
    _section(out, version, 0, b"")  # skeletons
    if _sizes(version):
        _section(out, version, 0, b"")  # assets (4.1+)
    _section(out, version, len(frame.labeled_markers),
             b"".join(_LM.pack(m.id, *m.position, m.size, m.params, m.residual) for m in frame.labeled_markers))
    _section(out, version, 0, b"")  # force plates
    _section(out, version, 0, b"")  # devices
    out += _SUFFIX3.pack(frame.timecode, frame.timecode_sub, frame.timestamp, frame.mid_exposure_ticks,
                         frame.data_received_ticks, frame.transmit_ticks)
    if _sizes(version):
        out += _PRECISION.pack(frame.precision_s, frame.precision_frac)
    out += _I16.pack(frame.params)
    out += _I32.pack(0)  # end-of-data tag
    return pack_message(NAT_FRAMEOFDATA, bytes(out))


def _open_section(r: _Reader, version, name: str, item_bytes: int) -> tuple[int, int | None]:
    n = r.count(f"{name} count", item_bytes)
    size = None
    if _sizes(version):
        size = r.i32(f"{name} byte count")
        if size < 0 or size > len(r.data) - r.pos:
            raise NatNetDecodeError("truncated", f"{r.what}: {name} byte count {size} exceeds the "
                                                 f"{len(r.data) - r.pos} bytes left")
    return n, size


def _close_section(r: _Reader, name: str, start: int, size: int | None) -> None:
    if size is not None and r.pos - start != size:
        raise NatNetDecodeError("malformed", f"{r.what}: {name} declares {size} bytes and takes {r.pos - start}")


def _read_channels(r: _Reader, what: str) -> None:
    r.i32(f"{what} id")
    for _ in range(r.count(f"{what} channel count", 4)):
        n = r.count(f"{what} channel frame count", 4)
        r.skip(4 * n, f"{what} channel values")


def decode_frame(payload: bytes, version: Version) -> FrameOfData:
    """A NAT_FRAMEOFDATA payload in `version`'s layout; every byte must be accounted for."""
    r = _Reader(payload, f"NAT_FRAMEOFDATA ({version_text(version)})")
    number = r.i32("frame number")

    n, size = _open_section(r, version, "marker sets", 5)
    start, sets = r.pos, {}
    for _ in range(n):
        name = r.cstring("marker set name")
        k = r.count("marker set marker count", 12)
        r.skip(12 * k, "marker positions")
        sets[name] = k
    _close_section(r, "marker sets", start, size)

    others, size = _open_section(r, version, "other markers", 12)
    start = r.pos
    r.skip(12 * others, "other marker positions")
    _close_section(r, "other markers", start, size)

    n, size = _open_section(r, version, "rigid bodies", _RB.size)
    start = r.pos
    bodies = []
    for _ in range(n):
        rid, x, y, z, qx, qy, qz, qw, err, params = r.unpack(_RB, "rigid body")
        bodies.append(RigidBodyData(rid, (x, y, z), (qx, qy, qz, qw), err, params & 0xFFFF))
    _close_section(r, "rigid bodies", start, size)

    skeletons, size = _open_section(r, version, "skeletons", 8)
    start = r.pos
    for _ in range(skeletons):
        r.i32("skeleton id")
        r.skip(_RB.size * r.count("skeleton bone count", _RB.size), "skeleton bones")
    _close_section(r, "skeletons", start, size)

    assets = 0
    if _sizes(version):
        assets, size = _open_section(r, version, "assets", 12)
        start = r.pos
        for _ in range(assets):
            r.i32("asset id")
            r.skip(_ASSET_RB.size * r.count("asset bone count", _ASSET_RB.size), "asset bones")
            r.skip(_ASSET_MK.size * r.count("asset marker count", _ASSET_MK.size), "asset markers")
        _close_section(r, "assets", start, size)

    n, size = _open_section(r, version, "labelled markers", _LM.size)
    start = r.pos
    markers = []
    for _ in range(n):
        mid, x, y, z, sz, params, residual = r.unpack(_LM, "labelled marker")
        markers.append(LabeledMarker(mid, (x, y, z), sz, params & 0xFFFF, residual))
    _close_section(r, "labelled markers", start, size)

    plates, size = _open_section(r, version, "force plates", 8)
    start = r.pos
    for _ in range(plates):
        _read_channels(r, "force plate")
    _close_section(r, "force plates", start, size)

    devices, size = _open_section(r, version, "devices", 8)
    start = r.pos
    for _ in range(devices):
        _read_channels(r, "device")
    _close_section(r, "devices", start, size)

    timecode, sub, stamp, mid, rx, tx = r.unpack(_SUFFIX3, "frame suffix")
    prec = r.unpack(_PRECISION, "precision timestamp") if _sizes(version) else (0, 0)
    params = r.unpack(_I16, "frame params")[0] & 0xFFFF
    r.unpack(_I32, "end-of-data tag")
    r.done()
    return FrameOfData(number, tuple(bodies), tuple(markers), stamp, mid, rx, tx, timecode, sub, prec[0], prec[1],
                       params, sets, others, skeletons, assets, plates, devices)


# --------------------------------------------------------------------------- clock mapping

class HostClockMap:
    """Motive's clock ticks -> host seconds.

    A datagram is only ever delayed on its way, so receipt - transmit is the clock offset
    plus a non-negative delay; its minimum over a block of frames is close to the offset. A
    line through the last `blocks` block minima follows the drift between the two crystals
    (tens of ppm: a few ms over a long run). A frame's time is its mid-exposure on this
    line: what the camera saw, when it saw it, on the host's clock.
    """

    def __init__(self, clock_hz: int, block_s: float = 0.5, blocks: int = 16):
        self.hz = float(clock_hz)
        self.block_s = block_s
        self._blocks: deque[tuple[float, float]] = deque(maxlen=blocks)
        self._block_start: float | None = None
        self._block_min: tuple[float, float] | None = None
        self._origin: int | None = None

    def seconds(self, ticks: int) -> float:
        """Server seconds since the first stamp seen (small numbers keep float precision)."""
        if self._origin is None:
            self._origin = ticks
        return (ticks - self._origin) / self.hz

    def offset(self, dev: float) -> float:
        pts = list(self._blocks)
        if self._block_min is not None:
            pts.append(self._block_min)
        if len(pts) < 3:
            return min(p[1] for p in pts)
        n = len(pts)
        mx = sum(p[0] for p in pts) / n
        my = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx if sxx > 0 else 0.0
        resid = min(p[1] - (my + slope * (p[0] - mx)) for p in pts)  # onto the envelope
        return my + slope * (dev - mx) + resid

    def map(self, transmit_ticks: int, host_rx: float, ticks: int) -> float:
        """Feed a frame's transmit stamp and receipt time; the host time of `ticks`."""
        tx = self.seconds(transmit_ticks)
        d = host_rx - tx
        if self._block_start is None:
            self._block_start = tx
        if self._block_min is None or d < self._block_min[1]:
            self._block_min = (tx, d)
        if tx - self._block_start >= self.block_s:
            self._blocks.append(self._block_min)
            self._block_start, self._block_min = tx, None
        dev = self.seconds(ticks)
        return min(dev + self.offset(dev), host_rx)


# --------------------------------------------------------------------------- transport

COMMAND, DATA = "command", "data"


class UdpTransport:
    """The NatNet channels on UDP, bound to one local address (never the wildcard).

    Unicast: one socket sends to the server's command port and receives both the command
    replies (source port = command port) and the frames (source port = data port), as
    NatNet 4 clients do. Multicast: frames arrive on a second socket bound to
    (group, data port), joined on the local address. `recv` tells the channel a datagram
    came in on; datagrams from anywhere else are counted in `foreign` and dropped.
    """

    def __init__(self, server: str = "127.0.0.1", command_port: int = 1510, data_port: int = 1511,
                 multicast: str = "", local: str | None = None):
        self.server = socket.gethostbyname(server)
        self.command_port = int(command_port)
        self.data_port = int(data_port)
        self.multicast = multicast
        self.local = local or _local_address_towards(self.server)
        self.foreign = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind((self.local, 0))
        self.mcast = None
        if multicast:
            m = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            m.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            m.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            try:
                m.bind((multicast, self.data_port))
                m.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                             socket.inet_aton(multicast) + socket.inet_aton(self.local))
            except OSError:
                m.close()
                self.sock.close()
                raise
            self.mcast = m
        self._socks = [self.sock] + ([self.mcast] if self.mcast else [])

    @property
    def address(self) -> str:
        return f"{self.server}:{self.command_port}"

    def send(self, datagram: bytes) -> None:
        self.sock.sendto(datagram, (self.server, self.command_port))

    def recv(self, timeout: float) -> tuple[bytes, str] | None:
        ready, _, _ = select.select(self._socks, [], [], timeout)
        for s in ready:
            data, (host, port) = s.recvfrom(1 << 16)
            if s is self.mcast:
                return data, DATA
            if host == self.server and port == self.command_port:
                return data, COMMAND
            if host == self.server and port == self.data_port:
                return data, DATA
            self.foreign += 1
        return None

    def close(self) -> None:
        for s in self._socks:
            s.close()


def _local_address_towards(server: str) -> str:
    """The local address the kernel routes to `server` from (a UDP connect sends nothing)."""
    if ipaddress.ip_address(server).is_loopback:
        return "127.0.0.1"
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.connect((server, 9))
        return probe.getsockname()[0]
    finally:
        probe.close()


# --------------------------------------------------------------------------- the driver

@dataclass(frozen=True)
class NatNetFrame(TrackerFrame):
    """A TrackerFrame plus what Motive reported: frame number, Motive's timestamp (s),
    per body its streaming id, quaternion (x, y, z, w; None when not tracked), mean marker
    error (m; None when not tracked); Motive's stamps (ticks) and the receipt time (host s)."""

    frame_number: int = 0
    timestamp: float = 0.0
    ids: dict[str, int] = field(default_factory=dict)
    quaternions: dict[str, np.ndarray | None] = field(default_factory=dict)
    marker_error: dict[str, float | None] = field(default_factory=dict)
    mid_exposure_ticks: int = 0
    transmit_ticks: int = 0
    received: float = 0.0


@dataclass
class NatNetStats:
    """Counters a procedure reports (dropped packets are counted, never hidden).

    received: per body, frames that carried it; tracked / untracked: of those, with the
    tracking-valid flag set / cleared; frames: frames decoded; gaps: frame numbers missing
    between decoded frames (lost datagrams or frames Motive did not send); out_of_order:
    frames older than the newest (dropped); truncated / trailing / malformed: datagrams
    that did not decode (see NatNetDecodeError); unknown_message: datagrams with a message
    id this driver does not handle; unrecognized: NAT_UNRECOGNIZED_REQUEST replies;
    unknown_body: rigid-body records whose id no model definition names; before_handshake:
    frames before NAT_SERVERINFO (dropped); overflow: frames discarded because nobody read
    `frames()`; system_latency_*: Motive's own (transmit - mid-exposure), s.
    """

    received: dict[str, int] = field(default_factory=dict)
    tracked: dict[str, int] = field(default_factory=dict)
    untracked: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    gaps: int = 0
    out_of_order: int = 0
    truncated: int = 0
    trailing: int = 0
    malformed: int = 0
    unknown_message: int = 0
    unrecognized: int = 0
    unknown_body: int = 0
    before_handshake: int = 0
    modeldefs: int = 0
    overflow: int = 0
    system_latency_mean: float = float("nan")
    system_latency_max: float = float("nan")


class NatNetTracker:
    """Tracker over a NatNet stream (see the module docstring).

    transport: a `UdpTransport` or anything with `send(datagram)`, `recv(timeout) ->
    (datagram, "command" | "data") | None`, `close()` and `address` (STYLE item 1: the
    driver gets its transport). bodies: the rigid-body names to report (default: every
    rigid body the model definitions name). stale_timeout: s without a frame before
    reads raise (`[mocap] stale_timeout`; its stale line gives the rate the frames had
    been coming at, from Motive's timestamps). keepalive: s between NAT_KEEPALIVEs in
    unicast (Motive forgets silent unicast clients). clock: host seconds for frame times
    (`time.time`, as ROS stamps); monotonic: for ages (injectable for tests).
    on_frame(frame, monotonic receipt time): called on the reader thread for each frame
    (benchmarks).

    `connect(timeout)` does the handshake (NAT_CONNECT until NAT_SERVERINFO, then
    NAT_REQUEST_MODELDEF until NAT_MODELDEF) and raises one line if it cannot.
    """

    def __init__(self, transport, bodies: Sequence[str] | None = None, *, stale_timeout: float = 2.0,
                 keepalive: float = 1.0, client: ConnectRequest = ConnectRequest(), max_buffer: int = 100_000,
                 clock: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic,
                 on_frame: Callable | None = None, poll: float = 0.05):
        if bodies is not None and len(set(bodies)) != len(bodies):
            raise ValueError(f"duplicate body names in {list(bodies)}")
        self.transport = transport
        self.wanted = None if bodies is None else tuple(bodies)
        self.bodies: tuple[str, ...] = self.wanted or ()
        self.stale_timeout = float(stale_timeout)
        self.keepalive = float(keepalive)
        self.client = client
        self._clock = clock
        self._mono = monotonic
        self._on_frame = on_frame
        self._poll = poll
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._buffer: deque[NatNetFrame] = deque()
        self._max_buffer = int(max_buffer)
        self._latest: NatNetFrame | None = None
        self.server: ServerInfo | None = None
        self.models: ModelDefinitions | None = None
        self._by_id: dict[int, RigidBodyDescription] = {}
        self._labels: dict[int, str] = {}  # labelled-marker id -> "<body>:<marker>"
        self._clockmap: HostClockMap | None = None
        self._last_number: int | None = None
        self._latency_sum = 0.0
        self.last_error = ""
        self.last_message = ""
        self._bad_streak = 0
        self.stats = NatNetStats()
        self._reset_body_stats()
        t0 = monotonic()
        self._last_rx = t0
        self._last_frame_rx = t0
        self._polled = t0
        self._last_keepalive = t0
        self._modeldef_asked = -math.inf
        self._ever_frame = False
        self._stamps: deque[float] = deque(maxlen=64)  # Motive's timestamps (s) of the newest frames: their rate
        self._reader_error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read_loop, name="natnet-reader", daemon=True)
        self._thread.start()

    def _reset_body_stats(self) -> None:
        for d in (self.stats.received, self.stats.tracked, self.stats.untracked):
            for b in self.bodies:
                d.setdefault(b, 0)

    @property
    def address(self) -> str:
        return getattr(self.transport, "address", "the NatNet server")

    @property
    def topics(self) -> dict[str, str]:
        """What each body arrives on, for messages (the ROS tracker's topic names)."""
        return {b: f"NatNet rigid body {b!r} from {self.address}" for b in self.bodies}

    connect_hint = ("check that Motive streams (Edit > Settings > Streaming: Enable, 'Rigid Bodies' on) or that "
                    "`rig sim --natnet` runs, and that [mocap] server, command_port and data_port match it")

    # -- handshake (caller thread) ----------------------------------------------------
    def connect(self, timeout: float = 5.0, retry: float = 0.25) -> ServerInfo:
        """Handshake within `timeout` s; returns the server's info. Raises NatNetConnectError
        (no server, or a rigid body asked for is not defined) or NatNetVersionError."""
        deadline = self._mono() + timeout
        sent = 0
        with self._cond:
            while self.server is None:
                left = deadline - self._mono()
                if left <= 0:
                    raise NatNetConnectError(
                        f"no NatNet server answered at {self.address} within {timeout:g} s ({sent} NAT_CONNECT "
                        f"sent); {self.connect_hint}")
                self._cond.release()
                try:
                    self.transport.send(encode_connect(self.client))
                finally:
                    self._cond.acquire()
                sent += 1
                self._cond.wait(min(retry, left))
            info = self.server
        if not supported(info.natnet_version):
            raise NatNetVersionError(
                f"{info.app_name} {version_text(info.app_version)} at {self.address} streams NatNet "
                f"{version_text(info.natnet_version)}; this driver decodes NatNet 3.0-3.1 and 4.x: set Motive's "
                "streaming bitstream to 3.1 or later (Motive 2.x or 3.x)")
        with self._cond:
            asked = 0
            while self.models is None:
                left = deadline - self._mono()
                if left <= 0:
                    raise NatNetConnectError(
                        f"{info.app_name} at {self.address} answered NAT_CONNECT but sent no model definitions "
                        f"within {timeout:g} s ({asked} NAT_REQUEST_MODELDEF sent); check Motive's streaming of "
                        "rigid bodies")
                self._cond.release()
                try:
                    self.transport.send(pack_message(NAT_REQUEST_MODELDEF))
                finally:
                    self._cond.acquire()
                asked += 1
                self._cond.wait(min(retry, left))
        if self.wanted is not None:
            defined = [rb.name for rb in self.models.rigid_bodies]
            missing = [b for b in self.wanted if b not in defined]
            if missing:
                raise NatNetConnectError(
                    f"{info.app_name} at {self.address} defines no rigid body named "
                    f"{', '.join(repr(b) for b in missing)}; it defines {', '.join(map(repr, defined)) or 'none'}: "
                    "name the rigid bodies in Motive as the rig expects (<arm>_yaw, <arm>_pitch_end, <arm>_tool ...)")
        return info

    # -- receiving (reader thread) ----------------------------------------------------
    def _read_loop(self) -> None:
        try:
            while not self._stop.is_set():
                got = self.transport.recv(self._poll)
                now = self._mono()
                with self._lock:
                    self._polled = now
                if got is not None:
                    self._handle(got[0], got[1], now)
                if (self.server is not None and not self.server.multicast and self.keepalive > 0
                        and now - self._last_keepalive >= self.keepalive):
                    self._last_keepalive = now
                    self.transport.send(pack_message(NAT_KEEPALIVE))
        except Exception as exc:  # noqa: BLE001 - the transport failed (or a bug): reads report it
            if not self._stop.is_set():
                with self._cond:
                    self._reader_error = exc
                    self._cond.notify_all()

    def _count_error(self, exc: NatNetDecodeError) -> None:
        setattr(self.stats, exc.kind, getattr(self.stats, exc.kind) + 1)
        self.last_error = str(exc)

    def _handle(self, datagram: bytes, channel: str, rx_mono: float) -> None:
        rx_host = self._clock()
        try:
            message_id, payload = split_message(datagram)
        except NatNetDecodeError as exc:
            with self._cond:
                self._count_error(exc)
                self._bad_streak += 1
            return
        accepted = None
        with self._cond:
            self._last_rx = rx_mono
            if message_id == NAT_SERVERINFO:
                try:
                    info = decode_server_info(payload)
                except NatNetDecodeError as exc:
                    self._count_error(exc)
                    return
                if self.server is None or info != self.server:
                    self.server = info
                    self._clockmap = HostClockMap(info.clock_hz) if info.clock_hz else None
                self._cond.notify_all()
            elif message_id == NAT_MODELDEF:
                if self.server is None or not supported(self.server.natnet_version):
                    self.stats.before_handshake += 1
                    return
                try:
                    self._set_models(decode_modeldef(payload, self.server.natnet_version))
                except NatNetDecodeError as exc:
                    self._count_error(exc)
                    return
                self._cond.notify_all()
            elif message_id == NAT_FRAMEOFDATA:
                if self.server is None or self.models is None or not supported(self.server.natnet_version):
                    self.stats.before_handshake += 1
                    return
                try:
                    data = decode_frame(payload, self.server.natnet_version)
                except NatNetDecodeError as exc:
                    self._count_error(exc)
                    self._bad_streak += 1
                    return
                self._bad_streak = 0
                frame = self._frame(data, rx_host)
                if frame is None:
                    return
                self._last_frame_rx = rx_mono
                self._ever_frame = True
                self._stamps.append(data.timestamp)
                if len(self._buffer) >= self._max_buffer:
                    self._buffer.popleft()
                    self.stats.overflow += 1
                self._buffer.append(frame)
                self._latest = accepted = frame
                self._cond.notify_all()
                if data.models_changed and rx_mono - self._modeldef_asked >= 0.5:
                    # Motive's asset list changed: names by id may have too (asked at most twice a second)
                    self._modeldef_asked = rx_mono
                    self.transport.send(pack_message(NAT_REQUEST_MODELDEF))
            elif message_id == NAT_UNRECOGNIZED_REQUEST:
                self.stats.unrecognized += 1
            elif message_id in (NAT_RESPONSE, NAT_MESSAGESTRING):
                self.last_message = payload.split(b"\0", 1)[0].decode("utf-8", "replace")
            else:
                self.stats.unknown_message += 1
        if accepted is not None and self._on_frame is not None:
            self._on_frame(accepted, rx_mono)

    def _set_models(self, models: ModelDefinitions) -> None:
        """Names by id from new model definitions (lock held)."""
        self.models = models
        self.stats.modeldefs += 1
        self._by_id = {rb.id: rb for rb in models.rigid_bodies}
        if self.wanted is None:
            self.bodies = tuple(rb.name for rb in models.rigid_bodies)
            self._reset_body_stats()
        wanted = set(self.bodies)
        self._labels = {}
        for rb in models.rigid_bodies:
            if rb.name in wanted:
                for k in range(len(rb.markers)):
                    self._labels[(rb.id & 0xFFFF) << 16 | (k + 1)] = f"{rb.name}:{rb.marker_label(k)}"

    def _frame(self, data: FrameOfData, rx_host: float) -> NatNetFrame | None:
        """The TrackerFrame of a decoded frame, or None if it is out of order (lock held)."""
        st = self.stats
        if self._last_number is not None:
            step = data.frame_number - self._last_number
            if step <= 0:
                st.out_of_order += 1
                return None
            st.gaps += step - 1
        self._last_number = data.frame_number
        hz = self.server.clock_hz
        if self._clockmap is not None and data.transmit_ticks:
            t = self._clockmap.map(data.transmit_ticks, rx_host, data.mid_exposure_ticks)
            latency = (data.transmit_ticks - data.mid_exposure_ticks) / hz
            self._latency_sum += latency
            st.system_latency_mean = self._latency_sum / (st.frames + 1)
            st.system_latency_max = latency if math.isnan(st.system_latency_max) else max(st.system_latency_max,
                                                                                        latency)
        else:
            t = rx_host
        st.frames += 1
        bodies: dict[str, Pose | None] = {b: None for b in self.bodies}
        quats: dict[str, np.ndarray | None] = {b: None for b in self.bodies}
        errors: dict[str, float | None] = {b: None for b in self.bodies}
        ids: dict[str, int] = {}
        valid = []
        for rb in data.rigid_bodies:
            desc = self._by_id.get(rb.id)
            if desc is None:
                st.unknown_body += 1
                continue
            name = desc.name
            if name not in bodies:
                continue
            ids[name] = rb.id
            st.received[name] += 1
            if not rb.tracking_valid:
                st.untracked[name] += 1
                continue
            st.tracked[name] += 1
            valid.append((name, rb))
        if valid:
            q = np.array([rb.quaternion for _, rb in valid], float)
            q /= np.linalg.norm(q, axis=1, keepdims=True)  # float32 on the wire: renormalise
            R = quat_xyzw_to_matrix(q)
            for k, (name, rb) in enumerate(valid):
                bodies[name] = Pose(t, np.array(rb.position, float), R[k], "mocap")
                quats[name] = q[k]
                errors[name] = float(rb.mean_error)
        markers: dict[str, np.ndarray | None] = {label: None for label in self._labels.values()}
        for m in data.labeled_markers:
            label = self._labels.get(m.id)
            if label is not None and not m.params & MARKER_OCCLUDED:
                markers[label] = np.array(m.position, float)
        return NatNetFrame(t=t, bodies=bodies, markers=markers, frame_number=data.frame_number,
                           timestamp=data.timestamp, ids=ids, quaternions=quats, marker_error=errors,
                           mid_exposure_ticks=data.mid_exposure_ticks, transmit_ticks=data.transmit_ticks,
                           received=rx_host)

    # -- Tracker interface (caller thread) --------------------------------------------
    def stream_age(self) -> float:
        """Seconds since the last frame, counted up to when the reader last polled (a
        process held off the CPU does not take a healthy stream for a stale one)."""
        with self._lock:
            return min(self._mono(), self._polled) - self._last_frame_rx

    def check(self) -> None:
        """Raise if the reader failed, the frames stopped decoding, or the stream is stale."""
        with self._lock:
            err, bad, last = self._reader_error, self._bad_streak, self.last_error
        if err is not None:
            raise NatNetError(f"NatNet stream from {self.address} failed: {err}")
        if bad >= 10:
            version = version_text(self.server.natnet_version) if self.server else "?"
            raise NatNetError(f"the last {bad} datagrams from {self.address} did not decode as NatNet {version} "
                              f"({last}); check Motive's streaming bitstream version")
        age = self.stream_age()
        if age > self.stale_timeout:
            if self._ever_frame:
                with self._lock:
                    rate = rate_of(self._stamps)
                silence = silence_text(age, rate, noun="frame", seconds=True)
            else:
                silence = f"no frame for {age:.3f} s (none ever arrived)"
            setting = "[mocap] stale_timeout"
            raise MocapStaleError(f"NatNet stream from {self.address}: {silence}, beyond {self.stale_timeout:g} s "
                                  f"({setting}). " + starved_text(setting, "Motive is streaming to this machine",
                                                                  "start its streaming and check the network"))

    def frames(self) -> list[NatNetFrame]:
        """Every frame received since the last call, oldest first (raises, keeping them, if
        the stream is stale or broken)."""
        self.check()
        with self._lock:
            out = list(self._buffer)
            self._buffer.clear()
        return out

    def latest(self) -> NatNetFrame:
        self.check()
        with self._lock:
            if self._latest is None:
                raise MocapStaleError(f"no NatNet frame received yet from {self.address}")
            return self._latest

    def wait_for_frames(self, count: int, timeout: float) -> bool:
        """Block until `count` frames are buffered."""
        deadline = self._mono() + timeout
        with self._cond:
            while len(self._buffer) < count:
                left = deadline - self._mono()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        """Say goodbye (unicast), stop the reader and close the transport."""
        if self._stop.is_set():
            return
        self._stop.set()
        try:
            if self.server is not None and not self.server.multicast:
                self.transport.send(pack_message(NAT_DISCONNECT))
        except OSError:
            pass
        self._thread.join(timeout=2.0)
        self.transport.close()


def open_natnet_tracker(mocap: dict, bodies: Sequence[str] | None, timeout: float, **kwargs) -> NatNetTracker:
    """The tracker of a `[mocap] driver = "natnet"` section, connected (handshake done)."""
    try:
        transport = UdpTransport(mocap["server"], mocap["command_port"], mocap["data_port"], mocap["multicast"])
    except OSError as exc:
        raise NatNetConnectError(f"cannot open the NatNet channels towards {mocap['server']}:{mocap['command_port']}"
                                 f"{' (multicast ' + mocap['multicast'] + ')' if mocap['multicast'] else ''}: "
                                 f"{exc.strerror or exc}; check [mocap] server and multicast in rig.toml") from None
    if "stale_timeout" in mocap:
        kwargs.setdefault("stale_timeout", mocap["stale_timeout"])
    tracker = NatNetTracker(transport, bodies, **kwargs)
    try:
        tracker.connect(timeout)
    except BaseException:
        tracker.close()
        raise
    return tracker
