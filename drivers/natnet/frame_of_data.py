"""NatNet frames of data (rigid bodies, labelled markers), encoded and decoded per bitstream version."""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.natnet.errors import NatNetDecodeError
from drivers.natnet.messages import _Reader, pack_message
from drivers.natnet.wire_format import (_ASSET_MK, _ASSET_RB, _I16, _I32, _LM, _PRECISION, _RB, _SUFFIX3,
                                        FRAME_MODELS_CHANGED, NAT_FRAMEOFDATA, RB_TRACKING_VALID, Version, _sizes,
                                        version_text)


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
