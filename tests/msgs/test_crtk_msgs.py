"""crtk_msgs as a real dVRK sees it: the bytes on the wire and the type on DDS.

The serialization tests compare rclpy's CDR encoding of OperatingState and StringStamped
with encodings built here by hand from the CDR rules (XCDR1, little endian, as Fast DDS
sends ROS 2 messages): a 4-byte encapsulation header 00 01 00 00, then each field in
declaration order, every primitive aligned to its own size counted from the end of that
header; a string is a uint32 length that counts the terminating NUL, the bytes, the NUL.
CDR leaves the value of padding bytes open and Fast CDR does not clear them (rclpy's
buffer shows whatever was in memory there), so padding positions are compared by count
and position only; the cases without padding are compared byte for byte in full.

The DDS test publishes and subscribes in one process over Fast DDS on a private domain
with localhost discovery, and reads the type name and type hash back from the ROS graph.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import struct
import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from crtk_msgs.msg import OperatingState, StringStamped  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BUILD_INFO = json.loads((REPO / "crtk_msgs" / "BUILD_INFO.json").read_text())

# The RIHS01 hashes that Jazzy's rosidl_generator_type_description gives for the .msg
# files of collaborative-robotics/crtk_msgs 1.3.0 itself (checked once by building them
# with the same generators): a dVRK built on Jazzy announces these in discovery.
UPSTREAM_HASHES = {
    "crtk_msgs/msg/OperatingState": "RIHS01_5cc57eea589b217fe5194bf2735b91d4a7f2dd5ac1245ae657f7ea7590c2c80e",
    "crtk_msgs/msg/StringStamped": "RIHS01_83efb802e6596e03f69ac322e3231037329946f2bd13ed48874d97f5b8f5db1d",
}


class CdrLE:
    """A little-endian CDR writer that remembers where it padded."""

    HEADER = b"\x00\x01\x00\x00"  # CDR_LE encapsulation, options 0

    def __init__(self):
        self.body = bytearray()
        self.padding: list[int] = []  # offsets in the whole buffer, header included

    def _align(self, size: int) -> None:
        while len(self.body) % size:
            self.padding.append(len(self.HEADER) + len(self.body))
            self.body.append(0)

    def int32(self, v: int) -> "CdrLE":
        self._align(4)
        self.body += struct.pack("<i", v)
        return self

    def uint32(self, v: int) -> "CdrLE":
        self._align(4)
        self.body += struct.pack("<I", v)
        return self

    def boolean(self, v: bool) -> "CdrLE":
        self.body.append(1 if v else 0)
        return self

    def string(self, s: str) -> "CdrLE":
        raw = s.encode() + b"\x00"
        self.uint32(len(raw))
        self.body += raw
        return self

    def header(self, sec: int, nanosec: int, frame_id: str) -> "CdrLE":
        # std_msgs/Header: builtin_interfaces/Time stamp (int32 sec, uint32 nanosec), string frame_id
        return self.int32(sec).uint32(nanosec).string(frame_id)

    def bytes(self) -> bytes:
        return self.HEADER + bytes(self.body)


def operating_state(sec, nanosec, frame_id, state, is_homed, is_busy) -> OperatingState:
    m = OperatingState(state=state, is_homed=is_homed, is_busy=is_busy)
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = sec, nanosec, frame_id
    return m


def string_stamped(sec, nanosec, frame_id, string) -> StringStamped:
    m = StringStamped(string=string)
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = sec, nanosec, frame_id
    return m


def assert_same_cdr(got: bytes, expected: CdrLE) -> None:
    want = expected.bytes()
    assert len(got) == len(want), f"{len(got)} bytes, expected {len(want)}: {got.hex(' ')} vs {want.hex(' ')}"
    masked = bytes(0 if i in expected.padding else b for i, b in enumerate(got))
    assert masked == want, f"\n got      {got.hex(' ')}\n expected {want.hex(' ')} (padding at {expected.padding})"


def test_import_path_and_fields():
    assert OperatingState.__module__ == "crtk_msgs.msg._operating_state"
    assert list(OperatingState.get_fields_and_field_types().items()) == [
        ("header", "std_msgs/Header"), ("state", "string"), ("is_homed", "boolean"), ("is_busy", "boolean")]
    assert list(StringStamped.get_fields_and_field_types().items()) == [
        ("header", "std_msgs/Header"), ("string", "string")]


def test_shipped_build_matches_the_definitions():
    """The shipped libraries were built from the .msg files in the tree (else: rerun
    msgs/build_crtk_msgs.py), for this platform, with the dVRK's type hashes."""
    for rel, digest in BUILD_INFO["sources"].items():
        assert hashlib.sha256((REPO / rel).read_bytes()).hexdigest() == digest, (
            f"{rel} changed since crtk_msgs/ was built: run .venv/bin/python msgs/build_crtk_msgs.py")
    assert sorted(p.name for p in (REPO / "msgs" / "crtk_msgs").rglob("*") if p.is_file()) == sorted(
        Path(rel).name for rel in BUILD_INFO["sources"])
    assert BUILD_INFO["type_hashes"] == UPSTREAM_HASHES


def test_operating_state_bytes_in_full():
    """No padding anywhere (frame_id "PSM" ends the header on a 4-byte boundary), so every
    byte is compared, against a literal written out field by field."""
    expected = bytes.fromhex(
        "00 01 00 00"                      # encapsulation: CDR, little endian
        "00 f1 53 65"                      # header.stamp.sec = 1700000000 (int32)
        "00 65 cd 1d"                      # header.stamp.nanosec = 500000000 (uint32)
        "04 00 00 00 50 53 4d 00"          # header.frame_id = "PSM": length 4 with the NUL
        "08 00 00 00 45 4e 41 42 4c 45 44 00"  # state = "ENABLED"
        "01"                               # is_homed = true
        "00"                               # is_busy = false
    )
    msg = operating_state(1_700_000_000, 500_000_000, "PSM", "ENABLED", True, False)
    assert serialize_message(msg) == expected
    assert expected == CdrLE().header(1_700_000_000, 500_000_000, "PSM").string("ENABLED").boolean(True).boolean(False).bytes()
    assert deserialize_message(expected, OperatingState) == msg


def test_string_stamped_bytes_in_full():
    expected = bytes.fromhex(
        "00 01 00 00"
        "2a 00 00 00"                      # header.stamp.sec = 42
        "07 00 00 00"                      # header.stamp.nanosec = 7
        "04 00 00 00 50 53 4d 00"          # header.frame_id = "PSM"
        "05 00 00 00 68 6f 6d 65 00"       # string = "home"
    )
    msg = string_stamped(42, 7, "PSM", "home")
    assert serialize_message(msg) == expected
    assert deserialize_message(expected, StringStamped) == msg


@pytest.mark.parametrize("sec, nanosec, frame_id, state, is_homed, is_busy", [
    (1_712_345_678, 123_456_789, "PSM1", "ENABLED", True, False),   # 3 padding bytes before state
    (0, 0, "", "DISABLED", False, False),                          # empty frame_id: 3 padding bytes
    (-1, 999_999_999, "PSM2_base", "FAULT", True, True),           # negative sec; 2 padding bytes
    (5, 1, "ECM", "PAUSED", False, True),
    (5, 1, "world", "", True, False),                              # empty state: length 1, just the NUL
])
def test_operating_state_round_trip(sec, nanosec, frame_id, state, is_homed, is_busy):
    msg = operating_state(sec, nanosec, frame_id, state, is_homed, is_busy)
    cdr = CdrLE().header(sec, nanosec, frame_id).string(state).boolean(is_homed).boolean(is_busy)
    assert_same_cdr(serialize_message(msg), cdr)
    back = deserialize_message(cdr.bytes(), OperatingState)
    assert back == msg
    assert (back.header.stamp.sec, back.header.frame_id, back.state, back.is_homed, back.is_busy) == (
        sec, frame_id, state, is_homed, is_busy)


@pytest.mark.parametrize("sec, nanosec, frame_id, string", [
    (1_712_345_678, 123_456_789, "PSM1", "enable"),
    (0, 0, "", "home"),
    (3, 4, "PSM2", ""),
    (3, 4, "MTML", "unhome"),
])
def test_string_stamped_round_trip(sec, nanosec, frame_id, string):
    msg = string_stamped(sec, nanosec, frame_id, string)
    cdr = CdrLE().header(sec, nanosec, frame_id).string(string)
    assert_same_cdr(serialize_message(msg), cdr)
    assert deserialize_message(cdr.bytes(), StringStamped) == msg


_domains = itertools.count()


@pytest.fixture
def ros_context(monkeypatch):
    # Domains 1-200 spread over the pid, as in the other single-process ROS tests; the
    # topic names are unique to this test as well.
    domain = 1 + (os.getpid() * 13 + next(_domains)) % 200
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.shutdown(context=ctx)


@pytest.mark.ros
def test_publish_and_subscribe_over_dds(ros_context):
    """An OperatingState and a StringStamped cross Fast DDS between two nodes, and the
    graph reports the ROS type names (which rmw_fastrtps demangles from the DDS names
    crtk_msgs::msg::dds_::OperatingState_ / StringStamped_; a name without that form is
    reported as it is) with the dVRK's type hashes."""
    prefix = f"/crtk_msgs_test_{os.getpid()}/PSM1"
    arm = rclpy.create_node("fake_dvrk_psm1", context=ros_context)
    client = rclpy.create_node("rig_client", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(arm)
    ex.add_node(client)
    try:
        got_state: list[OperatingState] = []
        got_command: list[StringStamped] = []
        state_pub = arm.create_publisher(OperatingState, f"{prefix}/operating_state", 10)
        client.create_subscription(OperatingState, f"{prefix}/operating_state", got_state.append, 10)
        command_pub = client.create_publisher(StringStamped, f"{prefix}/state_command", 10)
        arm.create_subscription(StringStamped, f"{prefix}/state_command", got_command.append, 10)

        sent_state = operating_state(12, 345, "PSM1", "ENABLED", True, True)
        sent_command = string_stamped(12, 346, "PSM1", "home")
        deadline = time.monotonic() + 20.0
        while (not got_state or not got_command) and time.monotonic() < deadline:
            state_pub.publish(sent_state)
            command_pub.publish(sent_command)
            ex.spin_once(timeout_sec=0.05)
        assert got_state, "no OperatingState arrived within 20 s"
        assert got_command, "no StringStamped arrived within 20 s"
        assert isinstance(got_state[0], OperatingState) and got_state[0] == sent_state
        assert isinstance(got_command[0], StringStamped) and got_command[0] == sent_command

        for topic, ros_type in ((f"{prefix}/operating_state", "crtk_msgs/msg/OperatingState"),
                                (f"{prefix}/state_command", "crtk_msgs/msg/StringStamped")):
            endpoints = client.get_publishers_info_by_topic(topic) + client.get_subscriptions_info_by_topic(topic)
            assert len(endpoints) == 2, endpoints
            for info in endpoints:
                assert info.topic_type == ros_type
                assert str(info.topic_type_hash) == UPSTREAM_HASHES[ros_type]
        assert (f"{prefix}/operating_state", ["crtk_msgs/msg/OperatingState"]) in client.get_topic_names_and_types()
    finally:
        ex.shutdown()
        arm.destroy_node()
        client.destroy_node()
