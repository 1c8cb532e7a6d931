"""The NatNet tracker driver: `NatNetTracker` (implements Tracker), its clock map and statistics.

OptiTrack Motive's NatNet stream (bitstream 3.x and 4.x). The protocol is written out in
`drivers/NATNET_PROTOCOL.md`; the package follows it byte for byte, bottom up:
`wire_format`, `messages` (framing, NAT_CONNECT, NAT_SERVERINFO), `model_definitions`
(NAT_MODELDEF: rigid bodies and their markers, marker sets; the other kinds are skipped),
`frame_of_data` (NAT_FRAMEOFDATA: every section is parsed, so a frame decodes only if its
byte count adds up exactly: a layout of the wrong version or a cut datagram cannot pass as
data), `udp` (the two NatNet channels: one client socket for commands and unicast frames,
plus a multicast socket when the stream is multicast), then this module:

- `HostClockMap`: Motive's high-resolution clock (ticks) onto this host's clock, by the
  lower envelope of (receipt - transmit) with a line through block minima for drift;
- `NatNetTracker`: the host driver. It is given a transport, runs a reader thread and
  implements `drivers.interfaces.Tracker`. Rigid bodies are named by the model
  definitions; a body whose tracking-valid flag is cleared is None in its frame.

The fake Motive server that speaks this protocol from the simulated rig is
`drivers.natnet.fake_motive.FakeMotive`.

Why our own decoder and not the `natnet` package on PyPI (0.3.0): see NATNET_PROTOCOL.md,
"Why not a maintained client" (it misreads NatNet 4.1 frame suffixes, cannot be given a
transport, prints instead of counting bad packets and binds the wildcard address).

Units: positions m, times s on the host clock (`time.time()`, as ROS stamps) unless a
name ends in `_ticks` (Motive's clock) ; quaternions (x, y, z, w) as on the wire.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from drivers.common.clock_offset import BlockMinima, envelope_line
from drivers.interfaces import Pose, TrackerFrame
from drivers.mocap.ros_tracker import MocapStaleError
from drivers.natnet.errors import NatNetConnectError, NatNetDecodeError, NatNetError, NatNetVersionError
from drivers.natnet.frame_of_data import FrameOfData, decode_frame
from drivers.natnet.messages import (ConnectRequest, ServerInfo, decode_server_info, encode_connect, pack_message,
                                     split_message)
from drivers.natnet.model_definitions import ModelDefinitions, RigidBodyDescription, decode_modeldef
from drivers.natnet.udp import UdpTransport
from drivers.natnet.wire_format import (MARKER_OCCLUDED, NAT_DISCONNECT, NAT_FRAMEOFDATA, NAT_KEEPALIVE,
                                        NAT_MESSAGESTRING, NAT_MODELDEF, NAT_REQUEST_MODELDEF, NAT_RESPONSE,
                                        NAT_SERVERINFO, NAT_UNRECOGNIZED_REQUEST, supported, version_text)
from drivers.common.quaternion import quat_xyzw_to_matrix
from rig.faults import rate_of, silence_text, starved_text


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
        self._minima = BlockMinima(block_s, blocks)
        self._origin: int | None = None

    def seconds(self, ticks: int) -> float:
        """Server seconds since the first stamp seen (small numbers keep float precision)."""
        if self._origin is None:
            self._origin = ticks
        return (ticks - self._origin) / self.hz

    def offset(self, dev: float) -> float:
        pts = list(self._minima.closed)
        if self._minima.current is not None:
            pts.append(self._minima.current)
        if len(pts) < 3:
            return min(p[1] for p in pts)
        return envelope_line(pts, dev)

    def map(self, transmit_ticks: int, host_rx: float, ticks: int) -> float:
        """Feed a frame's transmit stamp and receipt time; the host time of `ticks`."""
        tx = self.seconds(transmit_ticks)
        self._minima.add(tx, host_rx - tx)
        dev = self.seconds(ticks)
        return min(dev + self.offset(dev), host_rx)


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
    (datagram, "command" | "data") | None`, `close()` and `address` (the
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
