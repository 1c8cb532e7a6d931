"""Motion capture over ROS 2: rigid-body poses as geometry_msgs/PoseStamped per body.

Common mocap bridges publish one PoseStamped topic per rigid body: vrpn_client_ros on
`/vrpn_client_node/<body>/pose`, mocap4r2 and optitrack bridges on similar names. This
driver subscribes to `/<prefix>/<body>/pose` (prefix "mocap" by default) on a node it is
given (it never creates or spins one: the caller's executor does), and assembles the
per-body messages into TrackerFrames by header stamp.

Assembly: messages with the same stamp form one frame. A frame is emitted when each body
has reported for it, has already reported a later stamp (topics are ordered, so its
message for this frame will not come), or has sent nothing for `assembly_window` s of
receive time (a body that stopped publishing, e.g. occluded in a bridge that drops lost
bodies). Silence is judged by when messages arrive, not by how far apart their stamps
are: on a process that takes its messages late, one topic's backlog may be taken before
another's, and a stamp-distance rule then split each frame's bodies into frames of their
own (measured: 11 bodies at 120 Hz, two CPU burners, fewer than a third of the frames
whole). Bodies without a message in a frame are None. A message for a
stamp at or before the last emitted frame is late: it is counted and dropped, never
merged into a later frame. A stream that has not delivered a message for `stale_timeout`
s makes `frames()`/`latest()` raise MocapStaleError naming the body and topic, how long it
has been silent, the rate it had been coming at (from its header stamps), the rig.toml key
of the limit (`[mocap] stale_timeout`) and that a starved process looks the same as a
stopped bridge; frames received before that are kept and returned by the next `frames()`
call after recovery.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from drivers.common import cdr
from drivers.interfaces import Pose, TrackerFrame
from drivers.common.quaternion import quat_xyzw_to_matrix
from rig.faults import DeviceFault, rate_of, silence_text, starved_text


class MocapStaleError(DeviceFault):
    """A body's pose stream stopped for longer than the tracker's stale timeout."""


@dataclass
class MocapStats:
    """Counters a procedure reports (docs/recordings.md: dropped frames are counted, never hidden).

    received: messages accepted per body; late: a body's message arriving after its
    frame was emitted without it (dropped); duplicate: a second message for the same body
    and stamp (dropped);
    out_of_order: messages older than that body's newest but still merged in time;
    overflow: frames discarded because nobody read `frames()` for `max_buffer` frames;
    frames: frames emitted; incomplete: frames with at least one body None;
    missing: per body, frames in which it was None; latency: mean and max of
    (node clock at receipt - header stamp) in s, meaningful when both share a clock.
    """

    received: dict[str, int] = field(default_factory=dict)
    late: int = 0
    duplicate: int = 0
    malformed: int = 0
    out_of_order: int = 0
    overflow: int = 0
    frames: int = 0
    incomplete: int = 0
    missing: dict[str, int] = field(default_factory=dict)
    latency_mean: float = float("nan")
    latency_max: float = float("nan")


def pose_topic(prefix: str, body: str) -> str:
    """The PoseStamped topic of `body` under `prefix` ("" for `/<body>/pose`)."""
    prefix = prefix.strip("/")
    return f"/{prefix}/{body}/pose" if prefix else f"/{body}/pose"


class RosMocapTracker:
    """Tracker over ROS 2 PoseStamped topics, one per rigid body.

    node: an rclpy Node that someone else spins (docs/fakes.md: the driver gets its
    transport). bodies: rigid-body names. prefix: topic prefix (see `pose_topic`).
    stale_timeout: s without a message on any body's topic before reads raise (the
    `[mocap] stale_timeout` key; `rig.config.stale_default` derives its default from the
    frame rate: 2.0 s at any rate above 5 Hz). setting: that key's name, for the stale line.
    assembly_window: s of receive time a body may be silent before frames are emitted
    without it.
    reliable: subscribe RELIABLE (only matches reliable publishers) instead of the
    default BEST_EFFORT (matches both kinds, what bridges such as vrpn use).
    clock: monotonic seconds for the stale check (injectable for tests); polled: when the
    executor last looked for messages (`drivers.common.ros_session.RosSession.executor_time`): ages
    are counted up to then, so a starved process does not take healthy streams for stale.
    time_base: the clock of the waits and ages when it is not the wall's (`drivers.common.time_base.SimTime`:
    simulated time; `clock` and `polled` are then its own).
    Times in TrackerFrame.t are the header stamps in s; positions in m.
    """

    def __init__(self, node, bodies: Sequence[str], *, prefix: str = "mocap",
                 stale_timeout: float = 2.0, assembly_window: float = 0.25,
                 max_buffer: int = 100_000, qos_depth: int = 100, reliable: bool = False,
                 clock: Callable[[], float] = time.monotonic, polled: Callable[[], float] | None = None,
                 setting: str = "[mocap] stale_timeout", time_base=None):
        from geometry_msgs.msg import PoseStamped
        from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy

        if not bodies:
            raise ValueError("RosMocapTracker needs at least one body name")
        if len(set(bodies)) != len(bodies):
            raise ValueError(f"duplicate body names in {list(bodies)}")
        self.node = node
        self._ros_clock = node.get_clock()
        self.bodies = tuple(bodies)
        self.prefix = prefix
        self.topics = {b: pose_topic(prefix, b) for b in self.bodies}
        if not stale_timeout > 0:
            raise ValueError(f"stale_timeout must be > 0 s, got {stale_timeout}")
        self.stale_timeout = float(stale_timeout)
        self.setting = setting
        self.assembly_window = float(assembly_window)
        from drivers.common.time_base import WallTime

        self._time = time_base if time_base is not None else WallTime()
        if self._time.simulated:
            clock, polled = self._time.now, None
        self._clock = clock
        self._polled = polled
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._pending: dict[int, dict[str, Pose]] = {}
        self._newest_stamp: dict[str, int] = {b: -1 for b in self.bodies}
        self._last_emitted = -1
        self._emitted_bodies: dict[int, frozenset[str]] = {}  # recent frames, for duplicates
        self._emitted_order: deque[int] = deque()
        self._buffer: deque[TrackerFrame] = deque()
        self._max_buffer = int(max_buffer)
        self._latest: TrackerFrame | None = None
        t0 = clock()
        self._last_rx: dict[str, float] = {b: t0 for b in self.bodies}
        self._ever_rx: dict[str, bool] = {b: False for b in self.bodies}
        # header stamps (s) of each body's newest messages: the rate it had been coming at
        self._stamps: dict[str, deque[float]] = {b: deque(maxlen=64) for b in self.bodies}
        self._latency_sum = 0.0
        self._latency_n = 0
        self.stats = MocapStats(received={b: 0 for b in self.bodies},
                                missing={b: 0 for b in self.bodies})
        qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE if reliable
                         else ReliabilityPolicy.BEST_EFFORT)
        # raw: the bytes are read here (drivers.common.cdr), not made into rclpy message objects
        self._subs = [node.create_subscription(PoseStamped, self.topics[b],
                                               self._make_callback(b), qos, raw=True)
                      for b in self.bodies]

    # -- receiving (executor thread)

    def _make_callback(self, body: str):
        def on_pose(raw: bytes) -> None:
            try:
                stamp, frame, v = cdr.pose_stamped(raw)
                pose = Pose(t=stamp * 1e-9, position=np.array(v[:3], dtype=float),
                            rotation=quat_xyzw_to_matrix(np.array(v[3:], dtype=float)), frame=frame)
            except ValueError:  # not a PoseStamped's bytes (cdr.CdrError), or a zero quaternion
                with self._lock:
                    self.stats.malformed += 1
                return
            self._on_pose(body, stamp, pose)
        return on_pose

    def _on_pose(self, body: str, stamp: int, pose: Pose) -> None:
        """One body's pose, stamped `stamp` ns."""
        now_ros = self._ros_clock.now().nanoseconds
        with self._cond:
            self._last_rx[body] = self._clock()
            self._ever_rx[body] = True
            self._stamps[body].append(stamp * 1e-9)
            if stamp <= self._last_emitted:
                # a repeat of a message already in an emitted frame is a duplicate; a body
                # arriving after its frame left is late. Both are dropped.
                if body in self._emitted_bodies.get(stamp, ()):
                    self.stats.duplicate += 1
                else:
                    self.stats.late += 1
                return
            slot = self._pending.setdefault(stamp, {})
            if body in slot:
                self.stats.duplicate += 1
                return
            if stamp < self._newest_stamp[body]:
                self.stats.out_of_order += 1
            slot[body] = pose
            self.stats.received[body] += 1
            self._newest_stamp[body] = max(self._newest_stamp[body], stamp)
            latency = (now_ros - stamp) * 1e-9
            self._latency_sum += latency
            self._latency_n += 1
            self.stats.latency_mean = self._latency_sum / self._latency_n
            self.stats.latency_max = (latency if not np.isfinite(self.stats.latency_max)
                                      else max(self.stats.latency_max, latency))
            if self._flush():
                self._cond.notify_all()

    def _flush(self, force: bool = False) -> bool:
        """Emit pending frames that can no longer change, oldest first (lock held)."""
        emitted = False
        now = self._clock()
        if self._polled is not None:  # silence counts only while the executor was looking
            now = min(now, self._polled())
        silent_since = now - self.assembly_window
        for stamp in sorted(self._pending):
            slot = self._pending[stamp]
            complete = len(slot) == len(self.bodies)
            given_up = all(self._newest_stamp[b] > stamp or self._last_rx[b] < silent_since
                           for b in self.bodies if b not in slot)
            if not (complete or given_up or force):
                break  # keep frames in stamp order: later ones wait for this one
            del self._pending[stamp]
            bodies = {b: slot.get(b) for b in self.bodies}
            frame = TrackerFrame(t=stamp * 1e-9, bodies=bodies, markers={})
            if not complete:
                self.stats.incomplete += 1
                for b in self.bodies:
                    if b not in slot:
                        self.stats.missing[b] += 1
            if len(self._buffer) >= self._max_buffer:
                self._buffer.popleft()
                self.stats.overflow += 1
            self._buffer.append(frame)
            self._latest = frame
            self._last_emitted = stamp
            self._emitted_bodies[stamp] = frozenset(slot)
            self._emitted_order.append(stamp)
            if len(self._emitted_order) > 1000:
                del self._emitted_bodies[self._emitted_order.popleft()]
            self.stats.frames += 1
            emitted = True
        return emitted

    # -- Tracker interface (caller thread)

    def stale_ages(self) -> dict[str, float]:
        """Seconds since each body's last message (since construction if none yet)."""
        now = self._clock()
        if self._polled is not None:
            now = min(now, self._polled())
        with self._lock:
            return {b: now - self._last_rx[b] for b in self.bodies}

    def rate(self, body: str) -> float:
        """Hz at which `body`'s poses had been coming, from their header stamps (0.0 before two)."""
        with self._lock:
            return rate_of(self._stamps[body])

    def check_stale(self) -> None:
        """Raise MocapStaleError if any body's stream is older than stale_timeout (ClockStopped
        on simulated time that stood still)."""
        self._time.check()
        ages = self.stale_ages()
        stale = {b: a for b, a in ages.items() if a > self.stale_timeout}
        if stale:
            parts = []
            for b, a in stale.items():
                if self._ever_rx[b]:
                    parts.append(f"{b!r} on {self.topics[b]}: {silence_text(a, self.rate(b), seconds=True)}")
                else:
                    parts.append(f"{b!r} on {self.topics[b]}: no message for {a:.3f} s (never received)")
            from drivers.common.ros_session import domain_text

            raise MocapStaleError(f"mocap stream stale beyond {self.stale_timeout:g} s ({self.setting}): "
                                  + "; ".join(parts) + ". "
                                  + starved_text(self.setting, f"the mocap bridge runs on {domain_text()} and the "
                                                 "body is tracked", "start the bridge there"))

    def frames(self) -> list[TrackerFrame]:
        """Every frame assembled since the last call, oldest first.

        Raises MocapStaleError (keeping the buffered frames) if a stream is stale.
        """
        self.check_stale()
        with self._lock:
            if self._flush():  # frames waiting only for a body that has gone silent since
                self._cond.notify_all()
            out = list(self._buffer)
            self._buffer.clear()
        return out

    def latest(self) -> TrackerFrame:
        """The newest assembled frame; raises MocapStaleError if a stream is stale."""
        self.check_stale()
        with self._lock:
            self._flush()
            if self._latest is None:
                raise MocapStaleError("no mocap frame assembled yet from "
                                      + ", ".join(self.topics.values()))
            return self._latest

    def wait_for_frames(self, count: int, timeout: float) -> bool:
        """Block until `count` frames are buffered (needs the node spun elsewhere)."""
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while True:
                self._flush()
                if len(self._buffer) >= count:
                    return True
                left = deadline - tb.now()
                if left <= 0:
                    return False
                # a silent body's frames leave by time, not by a message: look again then
                tb.wait(self._cond, min(left, self.assembly_window))

    def flush_pending(self) -> None:
        """Emit every pending (incomplete) frame now, e.g. at the end of a recording."""
        with self._cond:
            self._flush(force=True)
            self._cond.notify_all()

    def close(self) -> None:
        """Stop receiving: destroys this tracker's subscriptions (not the node)."""
        for s in self._subs:
            self.node.destroy_subscription(s)
        self._subs = []
