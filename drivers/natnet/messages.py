"""NatNet message framing, the connect request and the server info."""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass

from drivers.natnet.errors import NatNetDecodeError
from drivers.natnet.wire_format import (_I32, CONNECT_OPTIONS, HEADER, MAX_PAYLOAD, MESSAGE_NAMES, NAME_FIELD,
                                        NAT_CONNECT, NAT_SERVERINFO, SENDER, SERVER_EXTRA, Version)


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
