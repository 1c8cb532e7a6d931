"""crtk_msgs as a real dVRK sees it: upstream's definitions, the bytes on the wire, the types on DDS.

Every message and service of collaborative-robotics/crtk_msgs 1.3.0 (commit 14b04fcf) is
shipped: msgs/crtk_msgs/msg and srv hold upstream's files byte for byte (checked against
upstream's git blob ids), the shipped build and its compiled libraries carry upstream's
RIHS01 type hashes, and every type imports and serializes.

The serialization tests compare rclpy's CDR encoding with encodings built here by hand
from the CDR rules (XCDR1, little endian, as Fast DDS sends ROS 2 messages): a 4-byte
encapsulation header 00 01 00 00, then each field in declaration order, every primitive
aligned to its own size (float64: 8) counted from the end of that header; a string is a
uint32 length that counts the terminating NUL, the bytes, the NUL; a sequence a uint32
count, then its elements; a nested message its fields in place; an empty request
(TriggerOperatingState) a single uint8 that rosidl adds. CDR leaves the value of padding
bytes open and Fast CDR does not clear them (rclpy's buffer shows whatever was in memory
there), so padding positions are compared by count and position only; the cases without
padding are compared byte for byte in full. rclpy's serialize_message sizes its buffer by
the type support's estimate, which for a fixed-size type is rounded up to 4 bytes and for a
sequence with no element still counts the elements' alignment: bytes past the end of the
message are that slack (a publisher sends the serialized length only), so those cases
compare the message's bytes and check that the hand-built bytes decode to the message.

The DDS tests publish and subscribe, and call QueryForwardKinematics and
TriggerOperatingState, in one process over Fast DDS on a private domain with localhost
discovery, and read the type names and type hashes back from the ROS graph.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib
import json
import os
import struct
import time
from pathlib import Path

import pytest

import rclpy  # noqa: E402  (a declared dependency: a broken install fails here)
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

import crtk_msgs  # noqa: E402
from crtk_msgs.msg import (  # noqa: E402
    CartesianImpedance, CartesianImpedanceHalfPlaneGains, JointServo, OperatingState, SetpointMode, StringStamped)
from crtk_msgs.srv import QueryForwardKinematics, TriggerOperatingState  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BUILD_INFO = json.loads((REPO / "crtk_msgs" / "BUILD_INFO.json").read_text())

# Upstream: collaborative-robotics/crtk_msgs at 14b04fcf0d5f3fe32d2b4d0dddd3d247a60e37c3
# (release 1.3.0). Its msg/ and srv/ files, with their git blob ids (`git ls-tree -r HEAD`
# in a clone of it): msgs/crtk_msgs must hold exactly these bytes.
UPSTREAM_BLOBS = {
    "msg/CartesianImpedance.msg": "d12942271615d23f030e2bb76ab3bfa3bcd4b0f5",
    "msg/CartesianImpedanceHalfPlaneGains.msg": "4c145711d650130fd3678c94e98eda420947dd79",
    "msg/CartesianServo.msg": "9fecad2f07964c769653a28cdbdcf880de3cb709",
    "msg/CartesianState.msg": "22e99924d8979f4eb4007aac9b46cf3c262946b1",
    "msg/JointServo.msg": "bb6b23a2da54a761fc39658b592a02aa0e9eef73",
    "msg/OperatingState.msg": "73d21f9dd0d040826b03509e3370eb8dbe2ace99",
    "msg/SetpointMode.msg": "bdcc55b147e3d1aba5fc4de4129bc90036e0a926",
    "msg/StringStamped.msg": "c97cbe3e47341085f45fc903be2121be69348919",
    "srv/QueryForwardKinematics.srv": "fa2f7b46a8cd73a9cb3973ef9654f5d75ba4f9a8",
    "srv/QueryInverseKinematics.srv": "275953fbe30952ef46e6d1e0c0b175d1ba02a42b",
    "srv/TriggerOperatingState.srv": "d345fc5f153d5d3858be7b8810e05e2e9a760eb9",
}

# The RIHS01 hashes of every type upstream's files define, recorded once from a build of
# the untouched upstream files, not of ours: `msgs/upstream_type_hashes.py` took them with
# `git show` from a clone of upstream at the commit above and ran Jazzy's `rosidl hash`
# (rosidl_adapter 4.6.6, rosidl_generator_type_description 4.6.6) on them against the
# std_msgs/geometry_msgs 5.3.6, builtin_interfaces/service_msgs 2.0.3 definitions of the
# ROS wheels; no CMake, no msgs/crtk_msgs. A dVRK built on Jazzy announces these in
# discovery. (OperatingState and StringStamped were recorded the same way before, from
# upstream's files at 1.3.0 with the same generators: the same two values.)
UPSTREAM_HASHES = {
    "crtk_msgs/msg/CartesianImpedance": "RIHS01_9b4e8adf1c59d8045d9bab6c639f8851ec89024ff8bc744fb5b3965143dde7d0",
    "crtk_msgs/msg/CartesianImpedanceHalfPlaneGains": "RIHS01_ab886080cad5164b93d0fb8de83181067f78df6fe72e7d5e0bf15028c7984560",
    "crtk_msgs/msg/CartesianServo": "RIHS01_0acfd530851bb1e631c6f590b6c51d151e2d1af0b34ee0665ac4322f054c7427",
    "crtk_msgs/msg/CartesianState": "RIHS01_edd33cdbe17e19f486ed3cba80b3c894627ea819a8f2b6ad9bdb8db55eac58e6",
    "crtk_msgs/msg/JointServo": "RIHS01_a09603ce45ff956c65ff7faf7b8cc9009ba4bc11e0741f9e5f03716747a0b1fe",
    "crtk_msgs/msg/OperatingState": "RIHS01_5cc57eea589b217fe5194bf2735b91d4a7f2dd5ac1245ae657f7ea7590c2c80e",
    "crtk_msgs/msg/SetpointMode": "RIHS01_3e679d1b5c3c04d77b57ea150b3363e26520f33efa75758631f0d80cc525fc12",
    "crtk_msgs/msg/StringStamped": "RIHS01_83efb802e6596e03f69ac322e3231037329946f2bd13ed48874d97f5b8f5db1d",
    "crtk_msgs/srv/QueryForwardKinematics": "RIHS01_5906fc58a120dbfa461f62abf0cd0d6e57d0967fa79ea4838b2d342e06d65323",
    "crtk_msgs/srv/QueryForwardKinematics_Event": "RIHS01_e8f15403422dfc08c6eb813de5c407301c2bb3fadc73c5c020c95e3765c5e68e",
    "crtk_msgs/srv/QueryForwardKinematics_Request": "RIHS01_2819ed79e134df1b3e6f9345894ef3cfc9ed17341cd9216c80f597c621598e9b",
    "crtk_msgs/srv/QueryForwardKinematics_Response": "RIHS01_27a16a13341247258c839f8f0924e81ab079da726f160a08bd638c34a743c1ab",
    "crtk_msgs/srv/QueryInverseKinematics": "RIHS01_a2ead2f28d548d1b8589033207d18095262a0a07cf3eb290cb4af77b679960be",
    "crtk_msgs/srv/QueryInverseKinematics_Event": "RIHS01_d99ded79f02f42e6bff4698034bb4862be302000336b9582da441ab976f3b74a",
    "crtk_msgs/srv/QueryInverseKinematics_Request": "RIHS01_80dcd3fe6a4a8672e86733a74633b4be8405902ec0bc592270debabb0548230a",
    "crtk_msgs/srv/QueryInverseKinematics_Response": "RIHS01_9753427a61f92b880494f06fcbd4b3bceb8ae7d790b2d1b98f5e2ff938b9c3cc",
    "crtk_msgs/srv/TriggerOperatingState": "RIHS01_364ceef23563859e687f916bb77ba0c376c081cccce83eb6c576e14a6f8f8372",
    "crtk_msgs/srv/TriggerOperatingState_Event": "RIHS01_1bfae7c74f9e39925bfb35dd677958babe1f4a2d51bc6a0b36a0881ecda6f9ef",
    "crtk_msgs/srv/TriggerOperatingState_Request": "RIHS01_64c528a3c2d63e6cc836789b47968145c326f9b0c7a96702aeb0da305bd13cd3",
    "crtk_msgs/srv/TriggerOperatingState_Response": "RIHS01_667597111a35afae9882129f952eaaacec77b123f2598cbac7c519dd6646b96c",
}
UPSTREAM_SERVICES = ("QueryForwardKinematics", "QueryInverseKinematics", "TriggerOperatingState")


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

    def uint8(self, v: int) -> "CdrLE":
        self.body.append(v)
        return self

    def float64(self, *vs: float) -> "CdrLE":
        for v in vs:
            self._align(8)
            self.body += struct.pack("<d", v)
        return self

    def float64_seq(self, vs) -> "CdrLE":
        self.uint32(len(vs))
        return self.float64(*vs)

    def string_seq(self, ss) -> "CdrLE":
        self.uint32(len(ss))
        for s in ss:
            self.string(s)
        return self

    def pose(self, position, orientation) -> "CdrLE":
        # geometry_msgs/Pose: Point (x, y, z), Quaternion (x, y, z, w), all float64
        return self.float64(*position, *orientation)

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


def assert_same_cdr(got: bytes, expected: CdrLE, slack: bool = False) -> None:
    """`got` is `expected` but for the values of padding bytes; with `slack`, rclpy's
    buffer may go on past the message (the estimate's slack, see the module docstring)."""
    want = expected.bytes()
    if slack:
        assert len(got) >= len(want), f"{len(got)} bytes, expected {len(want)}: {got.hex(' ')} vs {want.hex(' ')}"
        got = got[:len(want)]
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


def test_every_jazzy_python_is_shipped_and_its_build_is_current():
    """The Python side is shipped per ABI for every CPython the Jazzy wheels exist for
    (3.11, 3.12, 3.13 on Linux x86_64), each built from today's definitions; the four C
    libraries are one set for all (the build is reproducible: each ABI's build shipped the
    same bytes). This interpreter's ABI is one of them."""
    import sysconfig

    abis = BUILD_INFO["abis"]
    assert sorted(a["python"] for a in abis.values()) == ["3.11", "3.12", "3.13"]
    assert crtk_msgs.shipped_pythons() == ["3.11", "3.12", "3.13"]
    assert sysconfig.get_config_var("SOABI") in abis
    here = REPO / "crtk_msgs"
    for soabi, info in abis.items():
        assert info["sources"] == BUILD_INFO["sources"], f"{soabi} was built from older definitions: rebuild it"
        for name in ("libcrtk_msgs__rosidl_generator_py", "crtk_msgs_s__rosidl_typesupport_c",
                     "crtk_msgs_s__rosidl_typesupport_fastrtps_c", "crtk_msgs_s__rosidl_typesupport_introspection_c"):
            assert (here / f"{name}.{soabi}.so").is_file(), (soabi, name)
    # nothing of the one-ABI layout left over to shadow them
    assert not [p.name for p in here.glob("crtk_msgs_s__*.so") if p.name.count(".") == 1]


def test_a_python_without_libraries_is_told_in_one_line_which_and_what_to_do(monkeypatch):
    """On an interpreter the package ships nothing for, the import error names its Python,
    the ones shipped and the fix (the loader's own check, run as that interpreter sees it)."""
    import sysconfig

    real = sysconfig.get_config_var
    monkeypatch.setattr(sysconfig, "get_config_var",
                        lambda k: "cpython-314-x86_64-linux-gnu" if k == "SOABI" else real(k))
    with pytest.raises(ImportError) as err:
        crtk_msgs._load_libraries()
    text = str(err.value)
    assert "\n" not in text
    assert "no message libraries for Python" in text and "cpython-314-x86_64-linux-gnu" in text
    assert "shipped for Linux x86_64 CPython 3.11, 3.12, 3.13" in text and "msgs/build_crtk_msgs.py" in text


def _type(type_name: str):
    """The Python class of a ROS type name such as crtk_msgs/srv/QueryForwardKinematics_Request."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def test_sources_are_upstreams_files():
    """msgs/crtk_msgs/msg and srv hold upstream's files, byte for byte, and nothing else."""
    source = REPO / "msgs" / "crtk_msgs"
    here = {str(p.relative_to(source)) for kind in ("msg", "srv") for p in (source / kind).iterdir() if p.is_file()}
    assert here == set(UPSTREAM_BLOBS)
    for rel, blob in UPSTREAM_BLOBS.items():
        data = (source / rel).read_bytes()
        assert hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest() == blob, f"{rel} is not upstream's file"


def test_every_upstream_type_imports():
    """Each message, each service and its Request, Response and Event import from
    crtk_msgs.msg / crtk_msgs.srv, and each message type has its C type support."""
    assert {n.split("/")[2] for n in UPSTREAM_HASHES if n.startswith("crtk_msgs/srv/") and "_" not in n.split("/")[2]} == set(
        UPSTREAM_SERVICES)
    for type_name in UPSTREAM_HASHES:
        cls = _type(type_name)
        assert cls.__name__ == type_name.split("/")[2]
        if type_name.split("/")[1] == "srv" and cls.__name__ in UPSTREAM_SERVICES:
            assert (cls.Request, cls.Response, cls.Event) == tuple(
                _type(f"{type_name}_{part}") for part in ("Request", "Response", "Event"))
        else:
            cls.__class__.__import_type_support__()
            assert cls.__class__._TYPE_SUPPORT is not None, type_name
            assert deserialize_message(serialize_message(cls()), cls) == cls()
    assert list(CartesianImpedance.get_fields_and_field_types()) == [
        "header", "force_orientation", "force_position", "torque_orientation", "position_positive",
        "position_negative", "orientation_positive", "orientation_negative"]
    assert (SetpointMode.NONE, SetpointMode.POSITION, SetpointMode.VELOCITY, SetpointMode.EFFORT, SetpointMode.PVF) == (
        0, 1, 2, 4, 7)
    assert list(QueryForwardKinematics.Request.get_fields_and_field_types().items()) == [
        ("jp", "sequence<double>"), ("cp", "geometry_msgs/Pose")]
    assert list(TriggerOperatingState.Response.get_fields_and_field_types().items()) == [
        ("operating_state", "crtk_msgs/OperatingState")]


class _TypeHash(ctypes.Structure):
    # rosidl_type_hash_t (rosidl_runtime_c/type_hash.h): uint8_t version; uint8_t value[32]
    _fields_ = [("version", ctypes.c_uint8), ("value", ctypes.c_uint8 * 32)]


def test_compiled_libraries_carry_upstream_hashes():
    """The hash each type's C code returns (crtk_msgs__srv__QueryForwardKinematics__get_type_hash
    and so on, in the shipped libcrtk_msgs__rosidl_generator_c.so; what rmw announces in
    discovery and what the type description service answers with) is upstream's."""
    lib = ctypes.CDLL(str(Path(crtk_msgs.__file__).parent / "libcrtk_msgs__rosidl_generator_c.so"))
    for type_name, expected in UPSTREAM_HASHES.items():
        fn = getattr(lib, type_name.replace("/", "__") + "__get_type_hash")
        fn.restype, fn.argtypes = ctypes.POINTER(_TypeHash), [ctypes.c_void_p]
        h = fn(None).contents  # the generated function ignores its argument
        assert f"RIHS{h.version:02d}_{bytes(h.value).hex()}" == expected, type_name


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


def test_half_plane_gains_bytes_in_full():
    """Twelve float64, no padding: every byte compared against a literal."""
    g = CartesianImpedanceHalfPlaneGains()
    g.p.x, g.p.y, g.p.z = 1.0, 2.0, -0.5
    g.d.x, g.d.y, g.d.z = 0.25, 0.0, 3.0
    g.bias.z = -1.0
    g.deadband.x = 0.001
    expected = bytes.fromhex(
        "00 01 00 00"
        "00 00 00 00 00 00 f0 3f" "00 00 00 00 00 00 00 40" "00 00 00 00 00 00 e0 bf"   # p = (1, 2, -0.5)
        "00 00 00 00 00 00 d0 3f" "00 00 00 00 00 00 00 00" "00 00 00 00 00 00 08 40"   # d = (0.25, 0, 3)
        "00 00 00 00 00 00 00 00" "00 00 00 00 00 00 00 00" "00 00 00 00 00 00 f0 bf"   # bias = (0, 0, -1)
        "fc a9 f1 d2 4d 62 50 3f" "00 00 00 00 00 00 00 00" "00 00 00 00 00 00 00 00"   # deadband = (0.001, 0, 0)
    )
    assert serialize_message(g) == expected
    assert expected == CdrLE().float64(1.0, 2.0, -0.5, 0.25, 0.0, 3.0, 0.0, 0.0, -1.0, 0.001, 0.0, 0.0).bytes()
    assert deserialize_message(expected, CartesianImpedanceHalfPlaneGains) == g


def test_cartesian_impedance_bytes():
    """What the client sends on <arm>/servo_ci: the header ("PSM" ends it on an 8-byte
    boundary), two quaternions and a vector, four half-plane gains; no padding."""
    m = CartesianImpedance()
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 7, 9, "PSM"
    m.force_orientation.w, m.force_position.x, m.torque_orientation.z = 1.0, 0.1, 1.0
    m.position_positive.p.x, m.position_negative.d.y = 200.0, 5.0
    m.orientation_positive.bias.z, m.orientation_negative.deadband.x = 0.5, 0.01
    cdr = (CdrLE().header(7, 9, "PSM")
           .float64(0.0, 0.0, 0.0, 1.0).float64(0.1, 0.0, 0.0).float64(0.0, 0.0, 1.0, 1.0)
           .float64(200.0, *[0.0] * 11)
           .float64(0.0, 0.0, 0.0, 0.0, 5.0, *[0.0] * 7)
           .float64(*[0.0] * 8, 0.5, 0.0, 0.0, 0.0)
           .float64(*[0.0] * 9, 0.01, 0.0, 0.0))
    assert cdr.padding == []
    assert serialize_message(m) == cdr.bytes()
    assert deserialize_message(cdr.bytes(), CartesianImpedance) == m


@pytest.mark.parametrize("jp", [[], [0.1], [0.1, -0.2, 0.15, 0.0, 1.5, -1.5]])
def test_query_forward_kinematics_bytes(jp):
    """Request: the count, 4 padding bytes (the doubles align to 8), the joints, the pose.
    Response: the pose, the bool, 3 padding bytes, the string."""
    pose = ((0.01, -0.02, -0.1), (0.0, 0.7071067811865476, 0.0, 0.7071067811865476))
    request = QueryForwardKinematics.Request(jp=jp)
    (request.cp.position.x, request.cp.position.y, request.cp.position.z) = pose[0]
    (request.cp.orientation.x, request.cp.orientation.y, request.cp.orientation.z, request.cp.orientation.w) = pose[1]
    cdr = CdrLE().float64_seq(jp).pose(*pose)
    assert cdr.padding == [8, 9, 10, 11]
    assert_same_cdr(serialize_message(request), cdr)
    assert deserialize_message(cdr.bytes(), QueryForwardKinematics.Request) == request

    response = QueryForwardKinematics.Response(result=True, message=f"{len(jp)} joints")
    response.cp = request.cp
    cdr = CdrLE().pose(*pose).boolean(True).string(f"{len(jp)} joints")
    assert cdr.padding == [61, 62, 63]
    assert_same_cdr(serialize_message(response), cdr)
    assert deserialize_message(cdr.bytes(), QueryForwardKinematics.Response) == response


def test_joint_servo_and_setpoint_mode_bytes():
    """Sequences of strings, of float64 (an empty one too) and of a nested message of one uint8."""
    m = JointServo(name=["outer_yaw", "jaw"], position=[0.5], velocity=[], effort=[0.0, -1.25],
                   mode=[SetpointMode(value=SetpointMode.PV), SetpointMode(value=SetpointMode.F)])
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 1, 2, "PSM1"
    cdr = (CdrLE().header(1, 2, "PSM1").string_seq(["outer_yaw", "jaw"]).float64_seq([0.5]).float64_seq([])
           .float64_seq([0.0, -1.25]).uint32(2).uint8(3).uint8(4))
    assert_same_cdr(serialize_message(m), cdr, slack=True)
    assert deserialize_message(cdr.bytes(), JointServo) == m
    assert_same_cdr(serialize_message(SetpointMode(value=7)), CdrLE().uint8(7), slack=True)


def test_trigger_operating_state_bytes():
    """The empty request is one uint8 (rosidl's structure_needs_at_least_one_member, 0);
    the response an OperatingState in place."""
    assert_same_cdr(serialize_message(TriggerOperatingState.Request()), CdrLE().uint8(0), slack=True)
    assert deserialize_message(CdrLE().uint8(0).bytes(), TriggerOperatingState.Request) == TriggerOperatingState.Request()
    response = TriggerOperatingState.Response(
        operating_state=operating_state(3, 4, "PSM2", "PAUSED", True, False))
    cdr = CdrLE().header(3, 4, "PSM2").string("PAUSED").boolean(True).boolean(False)
    assert_same_cdr(serialize_message(response), cdr)
    assert deserialize_message(cdr.bytes(), TriggerOperatingState.Response) == response


@pytest.fixture
def ros_context(ros_env):
    # a domain claimed for the test (tests/conftest.py); the topic names are unique to
    # this test as well
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


@pytest.mark.ros
def test_services_round_trip_over_dds(ros_context):
    """A client calls QueryForwardKinematics (and TriggerOperatingState) on a server node
    over Fast DDS; the graph names the service types, and the request and reply endpoints
    (rq/...Request, rr/...Reply) carry upstream's hashes of the _Request and _Response types."""
    prefix = f"/crtk_msgs_test_{os.getpid()}/PSM1"
    arm = rclpy.create_node("fake_dvrk_psm1_services", context=ros_context)
    client_node = rclpy.create_node("rig_service_client", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(arm)
    ex.add_node(client_node)
    served: list[list[float]] = []

    def forward_kinematics(request, response):
        # a stand-in kinematics: the tip at (sum, count, first joint), orientation as given
        jp = list(request.jp)
        served.append(jp)
        response.cp.position.x, response.cp.position.y = float(sum(jp)), float(len(jp))
        response.cp.position.z = jp[0] if jp else 0.0
        response.cp.orientation = request.cp.orientation
        response.result, response.message = bool(jp), f"{len(jp)} joints"
        return response

    def trigger(request, response):
        response.operating_state = operating_state(1, 2, "PSM1", "ENABLED", True, False)
        return response

    def call(client, request):
        assert client.wait_for_service(timeout_sec=30.0), f"{client.srv_name} not served within 30 s"
        future = client.call_async(request)
        deadline = time.monotonic() + 30.0  # a guard against hanging, not a timing check
        while not future.done() and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        assert future.done(), f"no reply from {client.srv_name} within 30 s"
        return future.result()

    try:
        arm.create_service(QueryForwardKinematics, f"{prefix}/forward_kinematics", forward_kinematics)
        arm.create_service(TriggerOperatingState, f"{prefix}/operating_state_service", trigger)
        fk = client_node.create_client(QueryForwardKinematics, f"{prefix}/forward_kinematics")
        state = client_node.create_client(TriggerOperatingState, f"{prefix}/operating_state_service")

        request = QueryForwardKinematics.Request(jp=[0.1, -0.2, 0.15])
        request.cp.orientation.z, request.cp.orientation.w = 0.6, 0.8
        reply = call(fk, request)
        assert isinstance(reply, QueryForwardKinematics.Response)
        assert served == [[0.1, -0.2, 0.15]]
        assert (reply.cp.position.x, reply.cp.position.y, reply.cp.position.z) == (sum([0.1, -0.2, 0.15]), 3.0, 0.1)
        assert (reply.cp.orientation.z, reply.cp.orientation.w) == (0.6, 0.8)
        assert (reply.result, reply.message) == (True, "3 joints")
        empty = call(fk, QueryForwardKinematics.Request())
        assert (empty.result, empty.message) == (False, "0 joints")

        got = call(state, TriggerOperatingState.Request())
        assert got.operating_state == operating_state(1, 2, "PSM1", "ENABLED", True, False)

        services = dict(client_node.get_service_names_and_types())
        assert services[f"{prefix}/forward_kinematics"] == ["crtk_msgs/srv/QueryForwardKinematics"]
        assert services[f"{prefix}/operating_state_service"] == ["crtk_msgs/srv/TriggerOperatingState"]
        for service, name in ((f"{prefix}/forward_kinematics", "QueryForwardKinematics"),
                              (f"{prefix}/operating_state_service", "TriggerOperatingState")):
            for topic, part in ((f"rq{service}Request", "Request"), (f"rr{service}Reply", "Response")):
                endpoints = (client_node.get_publishers_info_by_topic(topic, no_mangle=True)
                             + client_node.get_subscriptions_info_by_topic(topic, no_mangle=True))
                assert len(endpoints) == 2, (topic, endpoints)
                for info in endpoints:
                    assert info.topic_type == f"crtk_msgs::srv::dds_::{name}_{part}_"
                    assert str(info.topic_type_hash) == UPSTREAM_HASHES[f"crtk_msgs/srv/{name}_{part}"]
    finally:
        ex.shutdown()
        arm.destroy_node()
        client_node.destroy_node()
