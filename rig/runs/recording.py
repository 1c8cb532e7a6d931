"""Recording a run: every device stream as ROS 2 messages in one MCAP file.

A run is a stream of documents: a `run_start` metadata record (procedure,
parameters, config snapshot, versions, seed, UTC start), one channel per device stream
written sample by sample (`/PSM1/measured_js`, `/PSM1/servo_jp`, `/loadcell/force`,
`/mocap/<body>/pose`, ...), and a `run_stop` metadata record (status, error, sample counts
per channel). Foxglove and `ros2 bag` open the file; `mcap_ros2` decodes it.

Timing: every write method takes `t`, the sample time in seconds on the run clock; it
becomes the header stamp and the MCAP log_time and publish_time in integer ns.

Threading: the sample methods may be called from any thread (a driver's reader thread
records its own stream); the calling thread only encodes a sample (a snapshot of its values, so the
caller may reuse its arrays) and appends it to a queue. A writer thread owns the MCAP
writer: chunking and zstd compression never stall a 1 kHz control loop, and a Ctrl-C or
SIGTERM raised in the main thread can never interrupt the MCAP writer half way through a
record. The queue is bounded; when it is full the caller waits (it never drops a sample),
and each such wait is counted and reported in `run_stop` and `stats()`.

Metadata values are strings (MCAP's rule). The fields named in `JSON_FIELDS` hold JSON
text; `read_recording()` decodes them.
"""

from __future__ import annotations

import atexit
import collections
import json
import math
import os
import platform
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Sequence

from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from rig.runs import ros_messages as rm
from rig.sealed_json import to_json

#: metadata fields stored as JSON text (everything else is a plain string)
JSON_FIELDS = frozenset({"parameters", "config", "seed", "counts", "overflow", "extra",
                         "hold_errors", "held", "steps"})

STATUSES = ("completed", "aborted", "failed", "dry-run")


class RecorderError(RuntimeError):
    """The recording could not be written (disk full, closed recorder, type clash)."""


def to_ns(t: float) -> int:
    """Seconds on the run clock -> integer ns (MCAP times are uint64, so t >= 0)."""
    if not (t >= 0.0) or math.isinf(t):  # also rejects NaN
        raise ValueError(f"sample time must be finite and >= 0 s, got {t!r}")
    return round(t * 1e9)


def git_revision(path: Path | None = None) -> str:
    """`git describe --always --dirty` of the source tree holding this package, or ""."""
    where = Path(path) if path else Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=40"],
                             cwd=where, capture_output=True, text=True, timeout=2.0)
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def package_version() -> str:
    try:
        from importlib.metadata import version
        return version("dvrk-rig")
    except Exception:  # not installed as a distribution: fall back to the source tree's
        from rig import __version__
        return __version__


def quat_xyzw_from_matrix(R) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) with w >= 0 of a 3x3 rotation matrix."""
    m = [[float(R[i][j]) for j in range(3)] for i in range(3)]
    tr = m[0][0] + m[1][1] + m[2][2]
    # Pick the largest of the four diagonal combinations so the square root is well away
    # from zero (Shepperd); any single formula loses precision near some rotation.
    if tr > max(m[0][0], m[1][1], m[2][2]):
        s = 2.0 * math.sqrt(1.0 + tr)
        w, x, y, z = 0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s
    elif m[0][0] >= m[1][1] and m[0][0] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        w, x, y, z = (m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s
    elif m[1][1] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        w, x, y, z = (m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        w, x, y, z = (m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    sign = 1.0 if w >= 0 else -1.0
    return (sign * x / n, sign * y / n, sign * z / n, sign * w / n)


def _floats(values, what: str, size: int | None = None) -> list[float]:
    # tolist() turns a numpy array into Python floats in one call; struct.pack then
    # refuses anything that is not a number, so a bad sample fails here, in the caller.
    seq = values.tolist() if hasattr(values, "tolist") else list(values)
    if size is not None and len(seq) != size:
        raise ValueError(f"{what}: expected {size} values, got {len(seq)}")
    return seq


_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


class Recorder:
    """Writes one run's `run.mcap`.

    Use `start(...)` once, then the sample methods (from any thread), then
    `close(status, error)` from the thread that owns the run; `close` drains the queue, writes `run_stop` and finishes the
    file (summary, indexes, footer) so any MCAP reader can seek in it.

    Args:
        path: the file to create (`run.mcap` in the run folder).
        compression: "zstd" (default), "lz4" or "none" for each chunk.
        chunk_size: bytes per chunk before compression; a hard kill (SIGKILL, power loss)
            loses at most the open chunk, everything else is on disk.
        queue_limit: samples waiting for the writer thread before the caller waits.
    """

    def __init__(self, path: str | os.PathLike, *, compression: str = "zstd",
                 chunk_size: int = 512 * 1024, queue_limit: int = 200_000):
        self.path = Path(path)
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
        self._file = open(self.path, "xb")  # never overwrite an earlier recording
        self._writer = McapWriter(self._file, chunk_size=chunk_size,
                                  compression=_COMPRESSION[compression])
        self._writer.start(profile="ros2", library=f"dvrk-rig {package_version()} (rig.records)")
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._topic_types: dict[str, str] = {}  # caller side: topic -> schema name
        self._written: dict[str, int] = collections.defaultdict(int)  # writer thread side
        self._queue: collections.deque = collections.deque()
        self._queue_limit = int(queue_limit)
        self._overflows = 0
        self._blocked_s = 0.0
        self._max_queue = 0
        self._error: BaseException | None = None
        self._closing = False
        self._closed = False
        self._started = False
        self._stop_record: dict | None = None
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._drain, name=f"recorder:{self.path.name}", daemon=True)
        self._thread.start()
        # A process that exits without close() (sys.exit in a script, an unhandled error
        # outside a Run) still gets a readable file with a run_stop that says so.
        atexit.register(self._close_at_exit)

    def _close_at_exit(self) -> None:
        if not self._closed:
            self.close("failed", "process exited without closing the recording")

    # ----------------------------------------------------------------- documents
    def start(self, procedure: str, *, parameters: dict | None = None, config: Any = None,
              seed: Any = None, utc_start: datetime | None = None, extra: dict | None = None) -> dict:
        """Write the `run_start` metadata record; returns it (values as written, decoded)."""
        if self._started:
            raise RecorderError("run_start was already written")
        self._started = True
        utc_start = utc_start or datetime.now(timezone.utc)
        record = {
            "procedure": procedure,
            "utc_start": utc_start.isoformat(),
            "parameters": parameters or {},
            "config": config if config is not None else {},
            "seed": seed,
            "package": "dvrk-rig",
            "package_version": package_version(),
            "git_revision": git_revision(),
            "python": platform.python_version(),
            "host": socket.gethostname(),
            "argv": " ".join(sys.argv),
        }
        if extra:
            record["extra"] = extra
        self.metadata("run_start", record)
        return record

    def metadata(self, name: str, data: dict) -> None:
        """Write a metadata record; values in JSON_FIELDS are stored as JSON text."""
        encoded = {k: (to_json(v) if k in JSON_FIELDS else ("" if v is None else str(v)))
                   for k, v in data.items()}
        self._put((None, "metadata", name, encoded, 0))

    def close(self, status: str = "completed", error: str | None = None,
              extra: dict | None = None) -> dict:
        """Drain, write `run_stop` (status, error, counts per channel) and finish the file.

        Returns the run_stop record (decoded). Calling it again returns the same record.
        """
        if self._closed:
            return self._stop_record
        if status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
        self._closing = True
        self._wake.set()
        self._thread.join()
        self._closed = True
        atexit.unregister(self._close_at_exit)
        stop = {"status": status, "error": error or "",
                "utc_stop": datetime.now(timezone.utc).isoformat(),
                "counts": dict(self._written),
                "overflow": {"events": self._overflows, "blocked_s": round(self._blocked_s, 6),
                             "max_queue": self._max_queue}}
        if extra:
            stop.update(extra)
        self._stop_record = stop
        try:
            if self._error is not None:
                raise RecorderError(f"writing {self.path} failed: {self._error}") from self._error
            self._writer.add_metadata("run_stop", {k: (to_json(v) if k in JSON_FIELDS else str(v))
                                                   for k, v in stop.items()})
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()
        return stop

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> dict:
        """Samples written per topic, samples still queued, queue overflow events."""
        return {"written": dict(self._written), "queued": len(self._queue),
                "overflow_events": self._overflows, "blocked_s": self._blocked_s,
                "max_queue": self._max_queue}

    # ------------------------------------------------------------------ samples
    def joint_state(self, topic: str, t: float, position: Sequence[float] = (),
                    velocity: Sequence[float] = (), effort: Sequence[float] = (),
                    names: Sequence[str] = (), frame_id: str = "") -> None:
        """sensor_msgs/JointState: position (rad; m for a prismatic joint), velocity
        (rad/s, m/s), effort (N m, N). Empty sequences are allowed (e.g. servo_jf carries
        efforts only)."""
        t_ns = to_ns(t)
        data = rm.encode_joint_state(t_ns, frame_id, tuple(names), _floats(position, "position"),
                                     _floats(velocity, "velocity"), _floats(effort, "effort"))
        self._message(topic, rm.JOINT_STATE, t_ns, data)

    def pose(self, topic: str, t: float, position: Sequence[float],
             quat_xyzw: Sequence[float], frame_id: str = "") -> None:
        """geometry_msgs/PoseStamped: position (m) and unit quaternion in (x, y, z, w) order."""
        t_ns = to_ns(t)
        data = rm.encode_pose_stamped(t_ns, frame_id, _floats(position, "position", 3),
                                      _floats(quat_xyzw, "quat_xyzw", 4))
        self._message(topic, rm.POSE_STAMPED, t_ns, data)

    def point(self, topic: str, t: float, position: Sequence[float], frame_id: str = "") -> None:
        """A Cartesian position (m) as a geometry_msgs/PoseStamped with the identity
        orientation (0, 0, 0, 1): for a tool tip whose orientation is neither measured nor
        commanded (the three-joint tip of the cooperative loop). Readers take the position
        only; the orientation carries nothing."""
        self.pose(topic, t, position, (0.0, 0.0, 0.0, 1.0), frame_id)

    def wrench(self, topic: str, t: float, force: Sequence[float],
               torque: Sequence[float] = (0.0, 0.0, 0.0), frame_id: str = "") -> None:
        """geometry_msgs/WrenchStamped: force (N) and torque (N m)."""
        t_ns = to_ns(t)
        data = rm.encode_wrench_stamped(t_ns, frame_id, _floats(force, "force", 3),
                                        _floats(torque, "torque", 3))
        self._message(topic, rm.WRENCH_STAMPED, t_ns, data)

    def tension(self, topic: str, t: float, tension: float, frame_id: str = "loadcell") -> None:
        """Load-cell tension (N, positive when stretched) as a WrenchStamped with force.x."""
        self.wrench(topic, t, (float(tension), 0.0, 0.0), (0.0, 0.0, 0.0), frame_id)

    def scalar(self, topic: str, t: float, value: float) -> None:
        """std_msgs/Float64 (no header: `t` is the log time only)."""
        t_ns = to_ns(t)
        self._message(topic, rm.FLOAT64, t_ns, rm.encode_float64(float(value)))

    def twist(self, topic: str, t: float, linear: Sequence[float], angular: Sequence[float]) -> None:
        """geometry_msgs/Twist: linear (m/s) and angular (rad/s) velocity; log time `t`."""
        t_ns = to_ns(t)
        self._message(topic, rm.TWIST, t_ns, rm.encode_twist(_floats(linear, "linear", 3),
                                                             _floats(angular, "angular", 3)))

    # Adapters for the device interface dataclasses (drivers/interfaces.py), by duck typing
    # so that recording does not import the drivers.
    def joint_state_sample(self, topic: str, state) -> None:
        """Record a JointState dataclass (t, position, velocity, effort, name)."""
        self.joint_state(topic, state.t, state.position, state.velocity, state.effort,
                         getattr(state, "name", ()))

    def pose_sample(self, topic: str, pose) -> None:
        """Record a Pose dataclass (t, position, rotation matrix, frame)."""
        self.pose(topic, pose.t, pose.position, quat_xyzw_from_matrix(pose.rotation),
                  getattr(pose, "frame", ""))

    def force_sample(self, topic: str, sample) -> None:
        """Record a ForceSample dataclass (t, force = tension in N)."""
        self.tension(topic, sample.t, sample.force)

    # ------------------------------------------------------------------ internals
    def _message(self, topic: str, schema: str, t_ns: int, data: bytes) -> None:
        known = self._topic_types.get(topic)
        if known is None:
            if not topic.startswith("/"):
                raise ValueError(f"topic must start with '/': {topic!r}")
            self._topic_types[topic] = schema
        elif known != schema:
            raise RecorderError(f"topic {topic} carries {known}, cannot also carry {schema}")
        self._put((topic, schema, t_ns, data, t_ns))

    def _put(self, item: tuple) -> None:
        if self._error is not None:
            raise RecorderError(f"writing {self.path} failed: {self._error}") from self._error
        if self._closing:
            raise RecorderError(f"{self.path} is closed")
        queue = self._queue
        queue.append(item)  # deque.append is atomic: no lock on the 1 kHz path
        depth = len(queue)
        if depth >= self._queue_limit:
            self._wait_for_room()
        elif depth > self._max_queue:
            self._max_queue = depth

    def _wait_for_room(self) -> None:
        # Back-pressure instead of loss: the caller waits until the writer has caught up
        # to half the limit. Counted, because a run that waits here is not keeping its rate.
        self._overflows += 1
        began = time.perf_counter()
        self._wake.set()
        while len(self._queue) > self._queue_limit // 2 and self._thread.is_alive():
            time.sleep(0.0005)
        self._blocked_s += time.perf_counter() - began
        self._max_queue = max(self._max_queue, self._queue_limit)
        if self._error is not None:
            raise RecorderError(f"writing {self.path} failed: {self._error}") from self._error

    def _drain(self) -> None:
        queue, writer, written = self._queue, self._writer, self._written
        schema_ids, channel_ids = self._schema_ids, self._channel_ids
        try:
            while True:
                try:
                    topic, kind, a, b, publish = queue.popleft()
                except IndexError:
                    if self._closing:
                        return
                    # Polling every 2 ms costs nothing measurable and keeps the caller
                    # free of any lock or notify on its hot path.
                    self._wake.wait(0.002)
                    self._wake.clear()
                    continue
                if topic is None:  # metadata: kind == "metadata", a = name, b = data
                    writer.add_metadata(a, b)
                    continue
                channel = channel_ids.get(topic)
                if channel is None:
                    schema = schema_ids.get(kind)
                    if schema is None:
                        schema = writer.register_schema(kind, SchemaEncoding.ROS2,
                                                        rm.DEFINITIONS[kind].encode())
                        schema_ids[kind] = schema
                    channel = writer.register_channel(topic, MessageEncoding.CDR, schema)
                    channel_ids[topic] = channel
                writer.add_message(channel, a, b, publish, written[topic])
                written[topic] += 1
        except BaseException as exc:  # keep it for the caller; the thread has no one to tell
            self._error = exc


# ---------------------------------------------------------------------- reading back
@dataclass
class Recording:
    """A run.mcap read back in one linear pass (works on unfinished and cut files too).

    `messages[topic]` is a list of (log_time_ns, decoded message) when decoded, else of
    (log_time_ns, raw CDR bytes). `finalised` is True when the file ends with its footer;
    `problem` says what stopped the read early (a truncated chunk, a missing footer).
    """

    path: Path
    metadata: dict[str, dict] = field(default_factory=dict)
    messages: dict[str, list] = field(default_factory=dict)
    schemas: dict[str, str] = field(default_factory=dict)  # every topic -> schema name
    finalised: bool = False
    problem: str = ""

    @property
    def start(self) -> dict | None:
        return self.metadata.get("run_start")

    @property
    def stop(self) -> dict | None:
        return self.metadata.get("run_stop")

    def counts(self) -> dict[str, int]:
        return {topic: len(msgs) for topic, msgs in self.messages.items()}


def decode_metadata(data: dict[str, str]) -> dict:
    """Metadata strings -> values (JSON_FIELDS parsed back)."""
    out = {}
    for k, v in data.items():
        if k in JSON_FIELDS:
            try:
                out[k] = json.loads(v)
            except json.JSONDecodeError:
                out[k] = v
        else:
            out[k] = v
    return out


def read_recording(path: str | os.PathLike, topics: Iterable[str] | None = None,
                   decode: bool = True) -> Recording:
    """Read a run.mcap: metadata always, messages of `topics` (all when None).

    Never raises on a damaged tail: whatever precedes the damage is returned and the
    damage is described in `problem`. Raises FileNotFoundError / McapError only when the
    file is missing or is not an MCAP file at all.
    """
    from mcap_ros2.decoder import DecoderFactory

    path = Path(path)
    wanted = set(topics) if topics is not None else None
    rec = Recording(path=path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    factory = DecoderFactory()
    with open(path, "rb") as f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            raise ValueError(f"{path} is not an MCAP file (bad magic)")
        f.seek(0)
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None or (wanted is not None and channel.topic not in wanted):
                        continue
                    if decode:
                        decoder = decoders.get(record.channel_id)
                        if decoder is None:
                            decoder = factory.decoder_for(channel.message_encoding,
                                                          schemas.get(channel.schema_id))
                            decoders[record.channel_id] = decoder
                        value = decoder(record.data) if decoder else record.data
                    else:
                        value = record.data
                    rec.messages[channel.topic].append((record.log_time, value))
                elif isinstance(record, Channel):
                    if record.id not in channels:
                        channels[record.id] = record
                        schema = schemas.get(record.schema_id)
                        rec.schemas[record.topic] = schema.name if schema else ""
                        if wanted is None or record.topic in wanted:
                            rec.messages.setdefault(record.topic, [])
                elif isinstance(record, Schema):
                    schemas.setdefault(record.id, record)
                elif isinstance(record, Metadata):
                    rec.metadata[record.name] = decode_metadata(record.metadata)
                elif isinstance(record, Footer):
                    rec.finalised = True
        except Exception as exc:  # a cut file ends inside a record: keep what came before
            rec.problem = f"file ends early ({type(exc).__name__}: {exc})".replace("()", "")
    if not rec.finalised and not rec.problem:
        rec.problem = "file has no footer (the recording was not finished)"
    return rec
