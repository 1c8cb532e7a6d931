"""NatNet model definitions (rigid-body descriptions), encoded and decoded per bitstream version."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from drivers.natnet.errors import NatNetDecodeError
from drivers.natnet.messages import _cstr, _Reader, pack_message
from drivers.natnet.wire_format import (_I32, _V3, DESC_CAMERA, DESC_DEVICE, DESC_FORCEPLATE, DESC_MARKERSET,
                                        DESC_RIGIDBODY, DESC_SKELETON, NAT_MODELDEF, Version, _sizes, version_text)


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
