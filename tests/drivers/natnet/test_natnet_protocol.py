"""Byte-level tests of the NatNet protocol and the tracker driver (no sockets, except the
one test of an absent server).

Frames and model definitions are built here by hand, field by field from
drivers/NATNET_PROTOCOL.md, and decoded to known values; the driver talks to
`ExpectedTransport`, which holds (datagram the client must send, datagrams the server
answers) pairs in order: a send that differs, or a pair left unused, fails the test.
"""

from __future__ import annotations

import re
import struct
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from drivers.interfaces import Tracker
from drivers.mocap.ros_tracker import MocapStaleError
from drivers.natnet.errors import NatNetConnectError, NatNetDecodeError, NatNetError, NatNetVersionError
from drivers.natnet.frame_of_data import FrameOfData, RigidBodyData, decode_frame, encode_frame
from drivers.natnet.messages import (ConnectRequest, ServerInfo, decode_connect, decode_server_info, encode_connect,
                                     encode_server_info, pack_message, split_message)
from drivers.natnet.model_definitions import ModelDefinitions, decode_modeldef, encode_modeldef
from drivers.natnet.tracker import NatNetTracker
from drivers.natnet.udp import COMMAND, DATA, UdpTransport
from drivers.natnet.wire_format import (FRAME_MODELS_CHANGED, NAT_FRAMEOFDATA, NAT_KEEPALIVE, NAT_MODELDEF,
                                        NAT_REQUEST_MODELDEF, NAT_UNRECOGNIZED_REQUEST)
from drivers.common.quaternion import quat_xyzw_to_matrix

DOC = Path(__file__).resolve().parents[3] / "drivers" / "NATNET_PROTOCOL.md"
V31, V40, V41, V42 = (3, 1, 0, 0), (4, 0, 0, 0), (4, 1, 0, 0), (4, 2, 0, 0)


def hx(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", "").replace("\n", ""))


def message(message_id: int, payload: bytes) -> bytes:
    return struct.pack("<HH", message_id, len(payload)) + payload


def cstr(s: str) -> bytes:
    return s.encode() + b"\0"


def i32(*v: int) -> bytes:
    return struct.pack(f"<{len(v)}i", *v)


def f32(*v: float) -> bytes:
    return struct.pack(f"<{len(v)}f", *v)


def section(version, items: list[bytes]) -> bytes:
    """count i32, (4.1+) byte count i32, items."""
    body = b"".join(items)
    return i32(len(items)) + (i32(len(body)) if version >= V41 else b"") + body


def rigid_body(rid, pos, quat, err, params) -> bytes:
    return i32(rid) + f32(*pos) + f32(*quat) + f32(err) + struct.pack("<h", params)


def labelled(mid, pos, size, params, residual) -> bytes:
    return i32(mid) + f32(*pos) + f32(size) + struct.pack("<h", params) + f32(residual)


def suffix(version, timestamp, mid, rx, tx, params=0, precision=(0, 0)) -> bytes:
    out = struct.pack("<II", 0, 0) + struct.pack("<d", timestamp) + struct.pack("<QQQ", mid, rx, tx)
    if version >= V41:
        out += struct.pack("<II", *precision)
    return out + struct.pack("<h", params) + i32(0)  # params, end-of-data tag


TOOL = ((0.5, -0.25, 1.0), (0.0, 0.0, 0.6, 0.8), 0.00025)
MARKER = (0.53, -0.25, 1.01)


def hand_frame(version, number=1234, params=0, tool_id=5, yaw_valid=False) -> bytes:
    """A frame with every section filled: a marker set, a legacy marker, two rigid bodies
    (the second, id 6, with tracking valid cleared unless yaw_valid), a skeleton of one bone,
    (4.1+) an asset with a bone and a marker, a labelled marker, a force plate with one
    channel of two samples and a device with no channel."""
    p = i32(number)
    p += section(version, [cstr("PSM1_tool") + i32(2) + f32(0.1, 0.2, 0.3, 0.4, 0.5, 0.6)])
    p += section(version, [f32(9.0, 9.0, 9.0)])
    p += section(version, [rigid_body(tool_id, *TOOL, 1),
                           rigid_body(6, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, 1 if yaw_valid else 0)])
    p += section(version, [i32(40, 1) + rigid_body(41, (1, 2, 3), (0, 0, 0, 1), 0.001, 1)])
    if version >= V41:
        p += section(version, [i32(70, 1) + rigid_body(71, (1, 2, 3), (0, 0, 0, 1), 0.001, 1)
                               + i32(1) + labelled(72, (1, 1, 1), 0.01, 2, 0.0)])
    p += section(version, [labelled(5 << 16 | 1, MARKER, 0.0095, 0x0E, 0.0001)])
    p += section(version, [i32(3, 1, 2) + f32(10.0, 11.0)])
    p += section(version, [i32(4, 0)])
    p += suffix(version, 10.25, 102_500_000, 102_510_000, 102_550_000, params, (1_700_000_000, 12345))
    return message(NAT_FRAMEOFDATA, p)


def hand_modeldef(version, tool_id=5) -> bytes:
    """A marker set, the rigid bodies PSM1_tool (id tool_id, 3 markers) and PSM1_yaw (id 6,
    no marker), and a skeleton of one bone (skipped)."""
    def rb(name, rid, markers):
        out = cstr(name) + i32(rid, -1) + f32(0.0, 0.0, 0.0)
        if version >= V42:
            out += f32(0.0, 0.0, 0.0, 1.0)
        out += i32(len(markers)) + b"".join(f32(*m) for m in markers) + i32(*[0] * len(markers))
        if version >= V40:
            out += b"".join(cstr(f"Marker{k + 1}") for k in range(len(markers)))
        return out

    items = [(0, cstr("PSM1_tool") + i32(3) + cstr("Marker1") + cstr("Marker2") + cstr("Marker3")),
             (1, rb("PSM1_tool", tool_id, [(0.03, 0.0, 0.01), (-0.015, 0.026, 0.01), (-0.015, -0.026, 0.025)])),
             (1, rb("PSM1_yaw", 6, [])),
             (2, cstr("Skel") + i32(40, 1) + rb("bone", 41, []))]
    p = i32(len(items))
    for kind, body in items:
        p += i32(kind) + (i32(len(body)) if version >= V41 else b"") + body
    return message(NAT_MODELDEF, p)


def server_info(version, clock_hz=10_000_000, data_port=1511) -> bytes:
    name = b"Motive".ljust(256, b"\0")
    return message(1, name + bytes((3, 1, 0, 0)) + bytes(version) + struct.pack("<QH?4B", clock_hz, data_port,
                                                                                  False, 0, 0, 0, 0))


# ----------------------------------------------------------------- framing and handshake

def test_headers_of_the_bodiless_messages_are_as_documented():
    assert pack_message(NAT_KEEPALIVE) == hx("0A 00 00 00")
    assert pack_message(NAT_REQUEST_MODELDEF) == hx("04 00 00 00")
    assert pack_message(NAT_UNRECOGNIZED_REQUEST) == hx("64 00 00 00")
    assert split_message(hx("07 00 02 00 AB CD")) == (7, hx("AB CD"))


def test_a_datagram_shorter_or_longer_than_its_byte_count_is_refused():
    with pytest.raises(NatNetDecodeError) as e:
        split_message(hx("07 00"))
    assert e.value.kind == "truncated"
    with pytest.raises(NatNetDecodeError) as e:
        split_message(hx("07 00 03 00 AB CD"))
    assert e.value.kind == "truncated" and "declares 3" in str(e.value)
    with pytest.raises(NatNetDecodeError) as e:
        split_message(hx("07 00 01 00 AB CD"))
    assert e.value.kind == "trailing"


def test_connect_is_the_269_byte_form_of_natnet_4_clients():
    datagram = encode_connect(ConnectRequest("dvrk-rig", (1, 0, 0, 0), (4, 1, 0, 0)))
    assert datagram[:4] == hx("00 00 0D 01") and len(datagram) == 273
    assert datagram[4:13] == b"dvrk-rig\0" and datagram[13:260] == bytes(247)
    assert datagram[260:] == bytes((1, 0, 0, 0, 4, 1, 0, 0, 0, 0, 0, 0, 0))
    assert decode_connect(datagram[4:]) == ConnectRequest("dvrk-rig", (1, 0, 0, 0), (4, 1, 0, 0), (0, 0, 0, 0))


def test_the_sdk_python_samples_and_bare_ping_connects_are_understood():
    block = bytearray(270)
    block[0:4] = b"Ping"
    block[265:269] = bytes((4, 2, 0, 0))
    req = decode_connect(bytes(block) + b"\0")
    assert (req.name, req.bitstream) == ("Ping", (4, 2, 0, 0))
    assert decode_connect(b"Ping\0").name == "Ping"


def test_server_info_bytes_decode_and_encode_both_ways():
    datagram = server_info(V41, 10_000_000, 1511)
    assert len(datagram) == 4 + 279
    info = decode_server_info(split_message(datagram)[1])
    assert info == ServerInfo("Motive", (3, 1, 0, 0), V41, 10_000_000, 1511, False, "")
    assert encode_server_info(info) == datagram
    bare = decode_server_info(split_message(datagram)[1][:264])  # an sSender only: no clock
    assert (bare.natnet_version, bare.clock_hz) == (V41, 0)
    with pytest.raises(NatNetDecodeError):
        decode_server_info(b"Motive\0")


# ----------------------------------------------------------------- frames

def test_the_documented_example_frames_decode_to_their_values_and_encode_back():
    examples = re.findall(r"```\n(07 00 [0-9A-F \n]+)```", DOC.read_text())
    assert len(examples) == 2
    for version, ex in zip((V31, V41), examples):
        datagram = hx(ex)
        f = decode_frame(split_message(datagram)[1], version)
        assert f.frame_number == 1234 and len(f.rigid_bodies) == 1
        rb = f.rigid_bodies[0]
        assert (rb.id, rb.tracking_valid) == (5, True)
        assert rb.position == (0.5, -0.25, 1.0)
        assert rb.quaternion == pytest.approx((0.0, 0.0, 0.6, 0.8), abs=1e-7)
        assert rb.mean_error == pytest.approx(0.00025, rel=1e-6)
        assert (f.timestamp, f.mid_exposure_ticks, f.data_received_ticks, f.transmit_ticks) == (
            10.25, 102_500_000, 102_510_000, 102_550_000)
        again = FrameOfData(1234, (RigidBodyData(5, (0.5, -0.25, 1.0), (0.0, 0.0, 0.6, 0.8), 0.00025, 1),),
                            timestamp=10.25, mid_exposure_ticks=102_500_000, data_received_ticks=102_510_000,
                            transmit_ticks=102_550_000)
        assert encode_frame(again, version) == datagram  # the fake's bytes are these bytes


@pytest.mark.parametrize("version", [V31, V40, V41, V42])
def test_a_hand_built_frame_with_every_section_decodes_to_known_values(version):
    f = decode_frame(split_message(hand_frame(version, params=FRAME_MODELS_CHANGED))[1], version)
    assert f.frame_number == 1234
    assert f.marker_sets == {"PSM1_tool": 2}
    assert (f.other_markers, f.skeletons, f.force_plates, f.devices) == (1, 1, 1, 1)
    assert f.assets == (1 if version >= V41 else 0)
    tool, yaw = f.rigid_bodies
    assert (tool.id, tool.position, tool.tracking_valid) == (5, (0.5, -0.25, 1.0), True)
    assert tool.quaternion == pytest.approx(TOOL[1], abs=1e-7)
    assert (yaw.id, yaw.tracking_valid) == (6, False)
    (m,) = f.labeled_markers
    assert (m.model_id, m.marker_id, m.params) == (5, 1, 0x0E)
    assert m.position == pytest.approx(MARKER, abs=1e-7) and m.residual == pytest.approx(1e-4)
    assert f.timestamp == 10.25 and f.transmit_ticks == 102_550_000
    assert f.models_changed
    assert (f.precision_s, f.precision_frac) == ((1_700_000_000, 12345) if version >= V41 else (0, 0))


@pytest.mark.parametrize("version", [V31, V41])
def test_every_truncation_of_a_frame_is_refused_as_truncated(version):
    payload = split_message(hand_frame(version))[1]
    for cut in range(len(payload)):
        with pytest.raises(NatNetDecodeError) as e:
            decode_frame(payload[:cut], version)
        assert e.value.kind == "truncated", (cut, str(e.value))
    with pytest.raises(NatNetDecodeError) as e:
        decode_frame(payload + b"\0", version)
    assert e.value.kind == "trailing"


def test_a_frame_of_another_version_never_decodes_as_data():
    f41 = split_message(hand_frame(V41))[1]
    f31 = split_message(hand_frame(V31))[1]
    for payload, version in ((f41, V31), (f41, V40), (f31, V41)):
        with pytest.raises(NatNetDecodeError):
            decode_frame(payload, version)
    # 3.1 and 4.0 frames share one layout (4.0 changed only the model definitions)
    assert decode_frame(f31, V40).frame_number == 1234


def test_a_section_whose_byte_count_disagrees_is_malformed():
    datagram = bytearray(hand_frame(V41))
    # the rigid-body section's byte count sits after its count: find the section and lie
    payload = bytes(datagram[4:])
    at = payload.index(i32(2) + i32(2 * 38))
    datagram[4 + at + 4:4 + at + 8] = i32(2 * 38 - 2)
    with pytest.raises(NatNetDecodeError) as e:
        decode_frame(split_message(bytes(datagram))[1], V41)
    assert e.value.kind == "malformed" and "rigid bodies" in str(e.value)


# ----------------------------------------------------------------- model definitions

@pytest.mark.parametrize("version", [V31, V40, V41, V42])
def test_model_definitions_name_the_rigid_bodies_and_their_markers(version):
    defs = decode_modeldef(split_message(hand_modeldef(version))[1], version)
    assert [(rb.name, rb.id) for rb in defs.rigid_bodies] == [("PSM1_tool", 5), ("PSM1_yaw", 6)]
    tool = defs.rigid_bodies[0]
    assert tool.markers == pytest.approx(np.array([[0.03, 0.0, 0.01], [-0.015, 0.026, 0.01],
                                                   [-0.015, -0.026, 0.025]]), abs=1e-7)
    assert [tool.marker_label(k) for k in range(3)] == ["Marker1", "Marker2", "Marker3"]
    assert tool.marker_names == (("Marker1", "Marker2", "Marker3") if version >= V40 else ())
    assert defs.marker_sets == {"PSM1_tool": ("Marker1", "Marker2", "Marker3")}
    assert defs.skipped == {2: 1}
    again = ModelDefinitions(defs.rigid_bodies)
    assert decode_modeldef(split_message(encode_modeldef(again, version))[1], version).rigid_bodies[0].name == \
        "PSM1_tool"


def test_model_definitions_of_another_version_or_cut_short_are_refused():
    p41 = split_message(hand_modeldef(V41))[1]
    with pytest.raises(NatNetDecodeError):
        decode_modeldef(p41, V31)
    for cut in range(0, len(p41), 7):
        with pytest.raises(NatNetDecodeError):
            decode_modeldef(p41[:cut], V41)


# ----------------------------------------------------------------- the driver

class ExpectedTransport:
    """A transport that plays the server from (datagram the client sends, [(datagram,
    channel) answered]) pairs; `inject` is the server sending on its own (frames)."""

    address = "127.0.0.1:1510"

    def __init__(self, pairs) -> None:
        self._pairs = deque(pairs)
        self._rx: deque[tuple[bytes, str]] = deque()
        self._cond = threading.Condition()
        self.errors: list[str] = []
        self.closed = False
        self.sent: list[bytes] = []

    def send(self, datagram: bytes) -> None:
        with self._cond:
            self.sent.append(bytes(datagram))
            if not self._pairs:
                self.errors.append(f"unexpected send {datagram[:8].hex(' ')}")
                return
            want, replies = self._pairs[0]
            if bytes(datagram) != want:
                self.errors.append(f"sent {datagram[:8].hex(' ')}..., expected {want[:8].hex(' ')}...")
                return
            self._pairs.popleft()
            self._rx.extend(replies)
            self._cond.notify_all()

    def inject(self, datagram: bytes, channel: str = DATA) -> None:
        with self._cond:
            self._rx.append((datagram, channel))
            self._cond.notify_all()

    def fail(self) -> None:
        """The socket goes away under the reader (an interface down, a closed descriptor)."""
        with self._cond:
            self.failed = True
            self._cond.notify_all()

    def recv(self, timeout: float):
        if getattr(self, "failed", False):
            raise OSError(9, "Bad file descriptor")
        with self._cond:
            if not self._rx:
                self._cond.wait(timeout)
            return self._rx.popleft() if self._rx else None

    def drained(self) -> bool:
        with self._cond:
            return not self._rx

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.errors, self.errors
        assert not self._pairs, f"unused pairs: {[p[0][:8].hex(' ') for p in self._pairs]}"


class ManualClock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def wait_for(pred, timeout=30.0) -> None:  # a guard against a hang, not a figure
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.002)


CONNECT = encode_connect()
REQUEST_MODELDEF = pack_message(NAT_REQUEST_MODELDEF)
DISCONNECT = (pack_message(9), [])  # NAT_DISCONNECT: a unicast client closing says goodbye


def opening(version, **kw):
    return [(CONNECT, [(server_info(version, **kw), COMMAND)]),
            (REQUEST_MODELDEF, [(hand_modeldef(version), COMMAND)])]


def connected(version, pairs=(), bodies=None, **kw):
    t = ExpectedTransport(opening(version) + list(pairs))
    kw.setdefault("keepalive", 0.0)
    tr = NatNetTracker(t, bodies, **kw)
    tr.connect(timeout=30.0, retry=30.0)
    return t, tr


@pytest.mark.parametrize("version", [V31, V41])
def test_session_a_frame_becomes_poses_by_name_and_a_lost_body_is_none(version):
    host = ManualClock(1000.0)
    t, tr = connected(version, [(REQUEST_MODELDEF, [(hand_modeldef(version), COMMAND)]), DISCONNECT], clock=host,
                      stale_timeout=1e9)
    assert isinstance(tr, Tracker)
    assert tr.bodies == ("PSM1_tool", "PSM1_yaw") and tr.server.natnet_version == version
    t.inject(hand_frame(version, params=FRAME_MODELS_CHANGED))  # models changed: the driver asks again
    wait_for(lambda: tr.stats.frames == 1 and tr.stats.modeldefs == 2)
    (f,) = tr.frames()
    assert (f.frame_number, f.timestamp) == (1234, 10.25)
    pose = f.bodies["PSM1_tool"]
    assert pose.position == pytest.approx([0.5, -0.25, 1.0])
    assert pose.rotation == pytest.approx(quat_xyzw_to_matrix(np.array([0.0, 0.0, 0.6, 0.8])), abs=1e-6)
    assert f.quaternions["PSM1_tool"] == pytest.approx([0.0, 0.0, 0.6, 0.8], abs=1e-6)
    assert f.marker_error["PSM1_tool"] == pytest.approx(0.00025)
    assert f.bodies["PSM1_yaw"] is None and f.quaternions["PSM1_yaw"] is None  # tracking valid cleared
    assert f.markers["PSM1_tool:Marker1"] == pytest.approx(MARKER)
    assert f.markers["PSM1_tool:Marker2"] is None  # not streamed: not seen
    # mid-exposure on the host clock: receipt minus Motive's (transmit - mid-exposure) of 5 ms
    assert f.t == pytest.approx(1000.0 - 0.005, abs=1e-9) and pose.t == f.t
    assert tr.stats.received == {"PSM1_tool": 1, "PSM1_yaw": 1}
    assert (tr.stats.tracked["PSM1_yaw"], tr.stats.untracked["PSM1_yaw"]) == (0, 1)
    assert tr.stats.system_latency_mean == pytest.approx(0.005)
    tr.close()
    assert t.sent[-1] == pack_message(9) and t.closed  # NAT_DISCONNECT, then the transport closes
    t.assert_done()


def test_bad_datagrams_are_counted_and_the_stream_goes_on():
    t, tr = connected(V41, [DISCONNECT], stale_timeout=1e9)
    good = hand_frame(V41, number=10)
    t.inject(good[:-9])                                      # a cut datagram
    t.inject(good + b"\0")                                   # a longer one
    t.inject(message(42, b"??"), COMMAND)                    # an unknown message id
    t.inject(pack_message(NAT_UNRECOGNIZED_REQUEST), COMMAND)  # the server refused something
    t.inject(hand_frame(V41, number=11, tool_id=9))          # a body no definition names
    t.inject(hand_frame(V41, number=14))                     # 12 and 13 never came
    t.inject(hand_frame(V41, number=13))                     # late: dropped
    t.inject(hand_frame(V41, number=15, yaw_valid=True))
    wait_for(t.drained)
    wait_for(lambda: tr.stats.frames == 3)
    st = tr.stats
    assert (st.truncated, st.trailing, st.unknown_message, st.unrecognized) == (1, 1, 1, 1)
    assert (st.unknown_body, st.gaps, st.out_of_order) == (1, 2, 1)
    frames = tr.frames()
    assert [f.frame_number for f in frames] == [11, 14, 15]
    assert frames[0].bodies["PSM1_tool"] is None  # its record had an unknown id
    assert frames[2].bodies["PSM1_yaw"] is not None
    tr.close()
    t.assert_done()


@pytest.mark.parametrize("version", [(2, 9, 0, 0), (5, 0, 0, 0), (3, 2, 0, 0)])
def test_a_version_the_driver_does_not_decode_is_one_line_and_no_frame_is_guessed(version):
    t = ExpectedTransport([(CONNECT, [(server_info(version), COMMAND)]), DISCONNECT])
    tr = NatNetTracker(t, keepalive=0.0, stale_timeout=1e9)
    with pytest.raises(NatNetVersionError) as e:
        tr.connect(timeout=30.0, retry=30.0)
    line = str(e.value)
    assert "\n" not in line and f"NatNet {version[0]}.{version[1]}" in line and "127.0.0.1:1510" in line
    assert "decodes NatNet 3.0-3.1 and 4.x" in line
    t.inject(hand_frame(V41))
    wait_for(t.drained)
    wait_for(lambda: tr.stats.before_handshake == 1)
    assert tr.stats.frames == 0
    tr.close()
    t.assert_done()


def test_frames_that_stop_decoding_stop_the_run_with_one_line():
    t, tr = connected(V41, stale_timeout=1e9)
    for n in range(10):
        t.inject(hand_frame(V31, number=n))  # a bitstream changed under us
    wait_for(lambda: tr.stats.truncated + tr.stats.malformed + tr.stats.trailing == 10)
    with pytest.raises(NatNetError) as e:
        tr.frames()
    assert "did not decode as NatNet 4.1" in str(e.value) and "\n" not in str(e.value)
    tr.close()


def test_a_transport_that_fails_under_the_reader_is_one_line_at_the_next_read():
    t, tr = connected(V41, [DISCONNECT], stale_timeout=1e9)
    t.fail()
    wait_for(lambda: tr._reader_error is not None)
    with pytest.raises(NatNetError) as e:
        tr.frames()
    assert str(e.value) == "NatNet stream from 127.0.0.1:1510 failed: [Errno 9] Bad file descriptor"
    tr.close()


def test_a_silent_stream_is_stale_on_the_drivers_clock():
    mono = ManualClock(50.0)
    t, tr = connected(V41, stale_timeout=0.5, monotonic=mono)
    t.inject(hand_frame(V41))
    wait_for(lambda: tr.stats.frames == 1)
    assert len(tr.frames()) == 1
    mono.t += 0.5
    wait_for(lambda: tr.stream_age() == pytest.approx(0.5))  # the reader has polled since
    tr.latest()
    mono.t += 0.01
    wait_for(lambda: tr.stream_age() > 0.5)
    with pytest.raises(MocapStaleError, match="no frame for 0.510 s"):
        tr.frames()
    tr.close()


def test_unicast_clients_keep_alive_once_a_second_of_the_drivers_clock():
    mono = ManualClock(50.0)
    t, tr = connected(V41, [(pack_message(NAT_KEEPALIVE), []), DISCONNECT], keepalive=1.0, monotonic=mono,
                      stale_timeout=1e9)
    mono.t += 1.0
    wait_for(lambda: pack_message(NAT_KEEPALIVE) in t.sent)
    tr.close()
    t.assert_done()


def test_a_rigid_body_the_rig_needs_but_motive_does_not_define_is_one_line():
    t = ExpectedTransport(opening(V41))
    tr = NatNetTracker(t, ["PSM1_tool", "PSM2_tool"], keepalive=0.0)
    with pytest.raises(NatNetConnectError) as e:
        tr.connect(timeout=30.0, retry=30.0)
    assert "defines no rigid body named 'PSM2_tool'" in str(e.value)
    assert "'PSM1_tool', 'PSM1_yaw'" in str(e.value) and "\n" not in str(e.value)
    tr.close()


def test_no_server_is_one_line_naming_the_address_and_what_to_do(free_ports):
    port = free_ports(2)  # claimed (tests/ros_domains.py) and free: nobody listens there
    tr = NatNetTracker(UdpTransport("127.0.0.1", port, port + 1), keepalive=0.0)
    with pytest.raises(NatNetConnectError) as e:
        tr.connect(timeout=0.3, retry=0.1)
    line = str(e.value)
    assert f"no NatNet server answered at 127.0.0.1:{port}" in line
    assert "rig sim --natnet" in line and "[mocap] server" in line and "\n" not in line
    tr.close()
