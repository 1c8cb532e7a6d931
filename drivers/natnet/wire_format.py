"""NatNet's message ids, flags, field layouts and the bitstream versions this driver speaks."""

from __future__ import annotations

import struct
from typing import Sequence

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

RB_TRACKING_VALID = 0x01          # rigid body params bit 0
MARKER_OCCLUDED = 0x01            # labelled marker params
MARKER_POINT_CLOUD_SOLVED = 0x02
MARKER_MODEL_SOLVED = 0x04
MARKER_HAS_MODEL = 0x08
FRAME_MODELS_CHANGED = 0x02       # frame suffix params

HEADER = struct.Struct("<HH")     # message id, payload bytes
NAME_FIELD = 256                  # sSender's fixed name field
SENDER = struct.Struct("<256s4B4B")
SERVER_EXTRA = struct.Struct("<QH?4B")  # clock Hz, data port, multicast, group address
CONNECT_OPTIONS = struct.Struct("<B4B")  # subscribed data only, requested bitstream version
MAX_PAYLOAD = 0xFFFF              # a u16 byte count

_I32 = struct.Struct("<i")
_I16 = struct.Struct("<h")
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
