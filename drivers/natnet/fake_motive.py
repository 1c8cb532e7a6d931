"""A fake OptiTrack Motive: the NatNet server side, on the loopback only, fed by the simulated rig.

`FakeMotive` answers the command channel as Motive does (NAT_CONNECT -> NAT_SERVERINFO,
NAT_REQUEST_MODELDEF -> NAT_MODELDEF, NAT_KEEPALIVE silently, an unknown request ->
NAT_UNRECOGNIZED_REQUEST) and sends NAT_FRAMEOFDATA from its data socket (source port =
the data port, which NatNet 4 clients check) to every unicast client, or once to a
multicast group. It binds 127.0.0.1 (or another loopback address) and nothing else; a
multicast stream leaves through the loopback interface with a TTL of 0, so no datagram
leaves the machine. The bytes are those of `drivers.natnet` (NATNET_PROTOCOL.md) in the
bitstream version it is given (3.0, 3.1, 4.0, 4.1).

`FakeMotiveOnWorld` is Motive watching the simulated rig: a `drivers.mocap.sim.SimTracker` on
the world's clock (marker noise, the rigid-body solve, occlusion and latency, as the
in-process twin of the tracker) whose delivered frames `pump()` hands to a FakeMotive. An occluded body stays
in its frame with the tracking-valid flag cleared (position 0, identity orientation, mean
error 0), as Motive streams a rigid body it lost; its visible markers are still sent as
labelled markers.

Clocks: Motive stamps frames with its high-resolution clock (`clock_hz` ticks per s since
`epoch` on the caller's timeline): the mid-exposure at capture, the transmit stamp when
sent. Its timestamp field is s since the first frame. Unicast clients that send nothing
(no keep-alive) for `client_timeout` s are forgotten, as Motive forgets them.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from drivers.natnet.errors import NatNetDecodeError
from drivers.natnet.frame_of_data import FrameOfData, LabeledMarker, RigidBodyData, encode_frame
from drivers.natnet.messages import ServerInfo, decode_connect, encode_server_info, pack_message, split_message
from drivers.natnet.model_definitions import ModelDefinitions, RigidBodyDescription, encode_modeldef
from drivers.natnet.wire_format import (MARKER_HAS_MODEL, MARKER_MODEL_SOLVED, MARKER_POINT_CLOUD_SOLVED, NAT_CONNECT,
                                        NAT_DISCONNECT, NAT_KEEPALIVE, NAT_REQUEST, NAT_REQUEST_FRAMEOFDATA,
                                        NAT_REQUEST_MODELDEF, NAT_RESPONSE, NAT_UNRECOGNIZED_REQUEST, RB_TRACKING_VALID,
                                        supported, version_text)
from drivers.common.quaternion import XYZW, reorder_quaternion

#: Motive releases and the bitstream they stream by default
MOTIVE_FOR = {(3, 0): (2, 1, 0, 0), (3, 1): (2, 3, 0, 0), (4, 0): (3, 0, 0, 0), (4, 1): (3, 1, 0, 0)}
VERSIONS = tuple(f"{a}.{b}" for a, b in MOTIVE_FOR)


def parse_version(text: str) -> tuple[int, int, int, int]:
    """"4.1" -> (4, 1, 0, 0); one of VERSIONS."""
    try:
        major, minor = (int(x) for x in text.split("."))
    except ValueError:
        raise ValueError(f"NatNet version {text!r}: expected one of {', '.join(VERSIONS)}") from None
    if (major, minor) not in MOTIVE_FOR:
        raise ValueError(f"NatNet version {text!r}: the fake Motive streams {', '.join(VERSIONS)}")
    return (major, minor, 0, 0)


def check_loopback(host: str) -> str:
    """`host` if it is a loopback address; the fake never serves anywhere else."""
    try:
        ok = ipaddress.ip_address(host).is_loopback and ipaddress.ip_address(host).version == 4
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(f"the fake Motive serves on the IPv4 loopback only (127.0.0.1), not {host!r}")
    return host


def check_multicast_group(group: str) -> str:
    try:
        ok = ipaddress.ip_address(group).is_multicast and ipaddress.ip_address(group).version == 4
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(f"multicast group {group!r} is not an IPv4 multicast address (224.0.0.0-239.255.255.255)")
    return group


@dataclass
class FakeMotiveStats:
    """connects: NAT_CONNECTs answered; modeldefs: NAT_MODELDEFs sent; keepalives; refused:
    requests answered NAT_UNRECOGNIZED_REQUEST; bad: datagrams that did not decode;
    frames: frames made; datagrams: frame datagrams sent; send_errors; expired: unicast
    clients forgotten for silence."""

    connects: int = 0
    modeldefs: int = 0
    keepalives: int = 0
    refused: int = 0
    bad: int = 0
    frames: int = 0
    datagrams: int = 0
    send_errors: int = 0
    expired: int = 0
    requests: dict[int, int] = field(default_factory=dict)


class FakeMotive:
    """Motive's NatNet server (see the module docstring).

    bodies: (name, marker offsets (n, 3) m from the pivot) of each rigid body, streamed
    with ids 1, 2, ... in that order. host: a loopback address. command_port, data_port:
    0 picks free ports (see the attributes after construction). multicast: a group
    address ("" for unicast). version: the bitstream (major, minor, 0, 0). rate: frames
    per s (for frame numbers). clock_hz, epoch: Motive's clock is (seconds - epoch) *
    clock_hz ticks, seconds on the caller's timeline (the `captured`/`sent` of `send`).
    """

    def __init__(self, bodies: Sequence[tuple[str, np.ndarray]], *, host: str = "127.0.0.1",
                 command_port: int = 1510, data_port: int = 1511, multicast: str = "",
                 version: tuple = (4, 1, 0, 0), app_name: str = "Motive", app_version: tuple | None = None,
                 rate: float = 120.0, clock_hz: int = 10_000_000, epoch: float = 0.0, client_timeout: float = 10.0,
                 marker_size: float = 0.0095):
        if not supported(version):
            raise ValueError(f"NatNet {version_text(version)}: the fake Motive streams {', '.join(VERSIONS)}")
        self.host = check_loopback(host)
        self.multicast = check_multicast_group(multicast) if multicast else ""
        self.version = tuple(version)
        self.rate = float(rate)
        self.clock_hz = int(clock_hz)
        self.epoch = float(epoch)
        self.client_timeout = float(client_timeout)
        self.marker_size = float(marker_size)
        self.descriptions = tuple(
            RigidBodyDescription(name, k + 1, np.asarray(offsets, float).reshape(-1, 3),
                                 tuple(f"Marker{j + 1}" for j in range(len(np.asarray(offsets).reshape(-1, 3)))))
            for k, (name, offsets) in enumerate(bodies))
        self._ids = {d.name: d.id for d in self.descriptions}
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.cmd.bind((self.host, command_port))
            self.data.bind((self.host, data_port))
            if self.multicast:
                self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(self.host))
                self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)  # never off this machine
                self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        except OSError:
            self.cmd.close()
            self.data.close()
            raise
        self.command_port = self.cmd.getsockname()[1]
        self.data_port = self.data.getsockname()[1]
        self.info = ServerInfo(app_name, tuple(app_version or MOTIVE_FOR.get(self.version[:2], (3, 1, 0, 0))),
                               self.version, self.clock_hz, self.data_port, bool(self.multicast), self.multicast)
        self._server_info = encode_server_info(self.info)
        self._modeldef = encode_modeldef(ModelDefinitions(self.descriptions), self.version)
        self.stats = FakeMotiveStats()
        self._lock = threading.Lock()
        self._clients: dict[tuple[str, int], float] = {}  # endpoint -> monotonic time last heard
        self._last_frame: bytes | None = None
        self._first: float | None = None
        self._last_number = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve_commands, name="fake-motive", daemon=True)

    def start(self) -> "FakeMotive":
        self._thread.start()
        return self

    @property
    def address(self) -> str:
        return f"{self.host}:{self.command_port}"

    @property
    def clients(self) -> list[tuple[str, int]]:
        with self._lock:
            return list(self._clients)

    def ticks(self, seconds: float) -> int:
        """Motive's clock at `seconds` on the caller's timeline."""
        return max(0, int(round((seconds - self.epoch) * self.clock_hz)))

    # -- command channel (its own thread) ---------------------------------------------
    def _serve_commands(self) -> None:
        self.cmd.settimeout(0.1)
        while not self._stop.is_set():
            try:
                datagram, src = self.cmd.recvfrom(1 << 16)
            except socket.timeout:
                continue
            except OSError:
                return  # closed
            self.handle(datagram, src)

    def _reply(self, datagram: bytes, dst) -> None:
        try:
            self.cmd.sendto(datagram, dst)
        except OSError:
            self.stats.send_errors += 1

    def handle(self, datagram: bytes, src: tuple[str, int]) -> None:
        """Answer one datagram from `src` on the command channel."""
        try:
            message_id, payload = split_message(datagram)
        except NatNetDecodeError:
            self.stats.bad += 1
            return
        self.stats.requests[message_id] = self.stats.requests.get(message_id, 0) + 1
        now = time.monotonic()
        with self._lock:
            if src in self._clients:
                self._clients[src] = now
        if message_id == NAT_CONNECT:
            decode_connect(payload)  # any client's form is accepted; the bitstream is Motive's setting
            with self._lock:
                if not self.multicast:
                    self._clients[src] = now
            self.stats.connects += 1
            self._reply(self._server_info, src)
        elif message_id == NAT_REQUEST_MODELDEF:
            self.stats.modeldefs += 1
            self._reply(self._modeldef, src)
        elif message_id == NAT_KEEPALIVE:
            self.stats.keepalives += 1
        elif message_id == NAT_DISCONNECT:
            with self._lock:
                self._clients.pop(src, None)
        elif message_id == NAT_REQUEST_FRAMEOFDATA and self._last_frame is not None:
            self._reply(self._last_frame, src)
        elif message_id == NAT_REQUEST and payload.split(b"\0", 1)[0] == b"Bitstream":
            self._reply(pack_message(NAT_RESPONSE, f"Bitstream,{version_text(self.version)}".encode() + b"\0"), src)
        else:
            self.stats.refused += 1
            self._reply(pack_message(NAT_UNRECOGNIZED_REQUEST), src)

    # -- data channel (the caller's thread) -------------------------------------------
    def frame_of(self, frame, captured: float, sent: float) -> FrameOfData:
        """The NatNet frame of a `drivers.mocap.sim.SimFrame` captured at `captured` and sent
        at `sent` (caller's timeline, s)."""
        if self._first is None:
            self._first = captured
        number = int(round((captured - self._first) * self.rate)) + 1
        number = max(number, self._last_number + 1)
        self._last_number = number
        bodies, markers = [], []
        order = getattr(frame, "quaternion_order", XYZW)
        for desc in self.descriptions:
            pose = frame.bodies.get(desc.name)
            if pose is None:
                bodies.append(RigidBodyData(desc.id, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, 0))
            else:
                q = reorder_quaternion(frame.quaternions[desc.name], order, XYZW)
                err = getattr(frame, "marker_error", {}).get(desc.name) or 0.0
                bodies.append(RigidBodyData(desc.id, tuple(map(float, pose.position)), tuple(map(float, q)),
                                            float(err), RB_TRACKING_VALID))
            for k in range(len(desc.markers)):
                m = frame.markers.get(f"{desc.name}:{desc.marker_label(k)}")
                if m is None:
                    continue  # hidden from the cameras: not streamed
                params = MARKER_POINT_CLOUD_SOLVED | MARKER_HAS_MODEL
                residual = 0.0
                if pose is not None:
                    params |= MARKER_MODEL_SOLVED
                    residual = float(np.linalg.norm(pose.rotation @ desc.markers[k] + pose.position - m))
                markers.append(LabeledMarker(desc.id << 16 | (k + 1), tuple(map(float, m)), self.marker_size,
                                             params, residual))
        mid = self.ticks(captured)
        return FrameOfData(number, tuple(bodies), tuple(markers), timestamp=captured - self._first,
                           mid_exposure_ticks=mid, data_received_ticks=min(self.ticks(captured + 0.001),
                                                                           self.ticks(sent)),
                           transmit_ticks=self.ticks(sent))

    def send(self, frame, captured: float, sent) -> int:
        """Stream one frame to every client (or the group); returns the datagrams sent.
        sent: the transmit time, or a function giving it (read when the frame is ready to
        go, as Motive stamps it)."""
        data = self.frame_of(frame, captured, captured if callable(sent) else sent)
        self.stats.frames += 1
        now = time.monotonic()
        with self._lock:
            for ep in [ep for ep, seen in self._clients.items() if now - seen > self.client_timeout]:
                del self._clients[ep]
                self.stats.expired += 1
            targets = [(self.multicast, self.data_port)] if self.multicast else list(self._clients)
        if not targets:
            return 0
        if callable(sent):
            t = sent()
            data = dataclasses.replace(data, transmit_ticks=self.ticks(t),
                                       data_received_ticks=min(data.data_received_ticks, self.ticks(t)))
        datagram = encode_frame(data, self.version)
        self._last_frame = datagram
        sent_n = 0
        for dst in targets:
            try:
                self.data.sendto(datagram, dst)
                sent_n += 1
            except OSError:
                self.stats.send_errors += 1
        self.stats.datagrams += sent_n
        return sent_n

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self.cmd.close()
        self.data.close()


class FakeMotiveOnWorld:
    """Motive watching the simulated rig (see the module docstring).

    world, clock: the simulated world and the clock that steps it; noise (m), latency (s),
    occlusion (probability per body and frame), rate (Hz), seed: as `SimTracker`;
    server: keyword arguments of FakeMotive (host, ports, multicast, version, epoch ...).
    """

    def __init__(self, world, clock, *, noise: float = 0.00025, latency: float = 0.005, occlusion: float = 0.0,
                 rate: float = 120.0, seed: int = 0, bodies: list[str] | None = None, **server):
        from drivers.mocap.sim import SimTracker

        self.clock = clock
        self.tracker = SimTracker(world, clock, noise=noise, latency=latency, occlusion=occlusion, rate=rate,
                                  quaternion_order=XYZW, seed=seed, bodies=bodies)
        self.motive = FakeMotive([(b, self.tracker.layouts[b]) for b in self.tracker.bodies], rate=rate, **server)

    def start(self) -> "FakeMotiveOnWorld":
        self.motive.start()
        return self

    def pump(self, offset: float = 0.0, sent=None) -> int:
        """Send the frames the tracker delivered since the last call. offset: the caller's
        timeline minus the clock's (s); sent: the transmit time, or a function giving it
        (default: offset + now)."""
        n = 0
        for f in self.tracker.frames():
            n += 1
            self.motive.send(f, offset + f.t, offset + self.clock.now() if sent is None else sent)
        return n

    def close(self) -> None:
        self.tracker.close()
        self.motive.close()
