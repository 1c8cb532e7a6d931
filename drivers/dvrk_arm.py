"""A dVRK arm over ROS 2 (rclpy) on the dVRK's CRTK topics: `RosArm`.

Topics under the arm's namespace (e.g. /PSM1), as the dVRK 2.3 / 2.4 ROS 2 bridge names them:

  subscribed   measured_js, setpoint_js          sensor_msgs/JointState
               measured_cp, local/measured_cp    geometry_msgs/PoseStamped
               body/measured_cf                  geometry_msgs/WrenchStamped
               operating_state                   crtk_msgs/OperatingState
               error                             std_msgs/String (the arm's error messages)
  published    servo_jp, servo_jf, move_jp       sensor_msgs/JointState (servo_jf: effort)
               state_command                     crtk_msgs/StringStamped
  console      /console/power_on, /console/home  std_msgs/Empty (dVRK 2.3; 2.4 names them
               /system/power_on, /system/home; console="auto" finds which from the graph)

Operating state (crtk_msgs, shipped with the package). A dVRK arm obeys motion commands
only when ENABLED and homed and drops the others. `ready()` brings the arm there as the
dVRK's Python client does: `enable`, then `home` on state_command, waiting with a timeout
for ENABLED and is_homed (a FAULT or PAUSED arm is not cleared: that is for a person at
the console). From then on the driver is in control: an operating_state that is no longer
ENABLED and homed (FAULT, DISABLED, PAUSED, unhomed) makes `measured_js()` and
`drain_js()` raise `ArmFault` with one line (the state and the arm's last message on
`error`), as a stale stream raises StaleStream, so the run aborts with the arms held.
`move_jp(wait=True)` waits on is_busy when the arm publishes operating_state: for the
flag to rise within `BUSY_RISE` s of the command, then to fall; without operating_state
(or if the flag never rises on an arm that is ready) it waits on the measured joints
(goal within `ARRIVAL_TOLERANCE` and at rest).

The whole arm. A dVRK PSM publishes six joints (outer_yaw, outer_pitch, outer_insertion,
outer_roll, outer_wrist_pitch, outer_wrist_yaw; older configurations say yaw, pitch, ...)
and its jaw on topics of its own. The rig's procedures model joints 1-3: the driver finds
them in every message by name (by position when a message carries no names), and gives
`measured_js()` those three. Commands of three joints are completed for the whole arm:
servo_jp and move_jp hold the wrist at `wrist_hold` (where it was when `ready()`
returned, else as last measured), servo_jf holds it with a soft PD of its own
(WRIST_KP, WRIST_KD) at the rate the procedure commands, `hold()` holds every joint where
it is. The jaw is left to the arm (the dVRK keeps its goal).

The dVRK publishes operating_state as events, on change only. A driver that subscribes
after the last change hears nothing until the next: `wait_for_state` then asks the arm's
`operating_state` service (crtk_msgs/TriggerOperatingState, as the dVRK's bridge serves
it), and `ready()` does so while it waits.

Threading model. The driver is given a node (STYLE item 1) and never creates one. Its
subscription callbacks only copy the newest message under a lock; they run on whatever
executor spins the node: with `spin=True` (the default) the driver starts its own
single-threaded executor on a daemon thread for this node; with `spin=False` the caller
spins it (one executor per node, e.g. `rig.devices.factory` spins one node shared by every
driver). Reads (`measured_js()` ...) and commands (`servo_jp()` ...) are called from the
procedure's thread: reads return the newest sample, commands publish at once (rclpy
publishers are thread-safe). A third thread, the watchdog, wakes every `watchdog / 5` s:
when measured_js has not arrived for longer than `watchdog` it publishes servo_jp at the
last measured position (the arm holds, if the controller still listens) and calls the
`on_stale` callbacks once per outage, so a run can abort even while the procedure is
blocked elsewhere. `measured_js()` itself raises `StaleStream` (topic and age) whenever
the stream is stale, so a procedure cannot act on old data.

Units: rad, m (joint 3), N m, N, s. Sample times are the header stamps (s since the epoch,
the publisher's ROS clock); the staleness age uses this host's monotonic clock, counted up
to when the executor last looked for messages (`polled`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

import numpy as np

from drivers import cdr
from drivers.crtk import (ARRIVAL_TOLERANCE, REST_VELOCITY, STATE_COMMANDS, ArmFault, OperatingState, StaleStream,
                          Wrench)
from drivers.interfaces import JointState, Pose
from drivers.quaternion import quat_xyzw_to_matrix

StaleCallback = Callable[[StaleStream], None]

#: s within which a move_jp's is_busy must rise before the wait falls back to positions
#: (the command crosses the wire and waits for the arm's next cycle; a dVRK raises it
#: within a cycle or two). On the wall clock a starved `rig sim` raised it later than that
#: under the test suite's load: the wait then falls back to positions, which is no fault.
BUSY_RISE = 0.5
#: s between repeats of a state command while `ready()` waits (one sent before the
#: arm's subscription matched would be lost; enable and home are idempotent on the dVRK)
RESEND = 1.0

#: N m/rad and N m s/rad of the wrist's hold under servo_jf: soft enough to be stable at a
#: 100 Hz command rate on the wrist's ~1e-5 kg m^2 (kd T / I < 1), enough to keep the tool
#: from drifting on its own friction
WRIST_KP = 0.2
WRIST_KD = 0.0005
#: the names of joints 1-3 in a dVRK PSM's measured_js: 2.x's, and the bare ones of some
#: configurations
_MODEL_JOINTS = (("outer_yaw", "yaw"), ("outer_pitch", "pitch"), ("outer_insertion", "insertion"))

#: the ROS type of <arm>/servo_ci, and the s of wall time a console's subscription to it is
#: looked for in the ROS graph (its endpoints are discovered together with its publishers,
#: already heard when this is asked: the wait covers a discovery still in flight)
SERVO_CI_TYPE = "crtk_msgs/msg/CartesianImpedance"
SERVO_CI_DISCOVERY = 2.0

#: the arm's state topics RosArm can subscribe (measured_js is always subscribed)
ALL_STREAMS = ("measured_js", "setpoint_js", "measured_cp", "local/measured_cp", "body/measured_cf")


def _stamp_seconds(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _vector(values, what: str) -> list[float]:
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        raise ValueError(f"{what}: empty command")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} contains a non-finite value: {v.tolist()}")
    return v.tolist()


def impedance_message(m, position, orientation=None, stiffness=(0.0, 0.0, 0.0), damping=(0.0, 0.0, 0.0),
                      bias=(0.0, 0.0, 0.0), deadband=(0.0, 0.0, 0.0), torque_stiffness=(0.0, 0.0, 0.0),
                      torque_damping=(0.0, 0.0, 0.0), force_orientation=None, torque_bias=(0.0, 0.0, 0.0)):
    """Fill the crtk_msgs/CartesianImpedance `m` as `RosArm.servo_ci` sends it (its
    arguments; the header is left to the caller) and return it."""
    from drivers.quaternion import matrix_to_quat_xyzw

    p = _vector(position, "servo_ci position")
    m.force_position.x, m.force_position.y, m.force_position.z = p[:3]
    o = m.force_orientation
    o.x, o.y, o.z, o.w = (0.0, 0.0, 0.0, 1.0) if force_orientation is None else (
        float(v) for v in matrix_to_quat_xyzw(np.asarray(force_orientation, float)))
    R = np.eye(3) if orientation is None else np.asarray(orientation, float)
    t = m.torque_orientation
    t.x, t.y, t.z, t.w = (float(v) for v in matrix_to_quat_xyzw(R))

    def three(values, sign):
        a = np.broadcast_to(np.asarray(values, float), (3,))
        return sign * float(a[0]), sign * float(a[1]), sign * float(a[2])

    force = [three(stiffness, -1.0), three(damping, -1.0), three(bias, 1.0), three(deadband, 1.0)]
    torque = [three(torque_stiffness, -1.0), three(torque_damping, -1.0), three(torque_bias, 1.0), (0.0, 0.0, 0.0)]
    for half in ("positive", "negative"):
        for gains, values in ((getattr(m, f"position_{half}"), force), (getattr(m, f"orientation_{half}"), torque)):
            for v, (x, y, z) in zip((gains.p, gains.d, gains.bias, gains.deadband), values):
                v.x, v.y, v.z = x, y, z
    return m


class RosArm:
    """Arm protocol over the dVRK CRTK ROS 2 topics (see the module docstring).

    node: an rclpy Node; namespace: the arm's topic namespace ("/PSM1"); watchdog: s of
    measured_js silence before the stream is stale; spin: run an executor thread for the
    node here; on_stale: callback(StaleStream) fired from the watchdog thread once per
    outage (more with `add_stale_callback`); console: the console's namespace
    ("/console", "/system", or "auto": the one the running system shows in the ROS graph);
    streams: which of `ALL_STREAMS` to subscribe (measured_js always: every fewer topic is
    less work for the executor); polled: the monotonic time at which the executor last
    looked for messages (`drivers.ros_session.RosSession.executor_time`): the staleness age is
    counted up to then, so that a starved process never takes a healthy stream for a stale
    one (None: up to now, for an executor that is never starved); states: read
    operating_state and send state_command (False: neither, as on a controller without
    the CRTK state machine); setting: the rig.toml key of `watchdog`, named by a stale
    stream's line (default `[arms.<name>] watchdog`, the name from the namespace);
    control_node: the node of the operating_state and error events, the operating_state
    service and state_command (`drivers.ros_session.RosSession.control`: they must not
    queue behind the streams; default `node`); time_base: the clock every wait, timeout
    and stream age is on (`drivers.time_base`: the wall clock by default, or a simulator's
    /clock in lockstep, whose waits free the world and whose commands are counted).
    """

    def __init__(self, node, namespace: str, watchdog: float = 0.05, *, spin: bool = True,
                 on_stale: StaleCallback | None = None, console: str = "/console", qos_depth: int = 10,
                 streams: tuple[str, ...] = ALL_STREAMS, polled: Callable[[], float] | None = None,
                 states: bool = True, setting: str | None = None, control_node=None, time_base=None):
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState as JointStateMsg
        from std_msgs.msg import Empty, String

        if watchdog <= 0:
            raise ValueError(f"watchdog must be > 0 s, got {watchdog}")
        self.node = node
        self.control_node = node if control_node is None else control_node
        self.namespace = "/" + namespace.strip("/")
        self.name = self.namespace.strip("/").split("/")[-1]
        self.watchdog = float(watchdog)
        #: the rig.toml key of the watchdog, for the stale stream's line
        self.setting = setting or f"[arms.{self.name}] watchdog"
        self._polled = polled
        #: the loop clock of the rig this arm belongs to (set by whoever paces its commands,
        #: `rig.devices.factory`): a run reports its ticks' timing from it
        self.clock = None
        from drivers.time_base import WallTime

        self._time = time_base if time_base is not None else WallTime()
        self._JointState = JointStateMsg
        self._Empty = Empty
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        # every measured_js since the last drain_js() (a few seconds at the dVRK's rates)
        self._js_log: deque[JointState] = deque(maxlen=4096)
        self._js: JointState | None = None
        self._js_rx: float | None = None  # time_base.now() of the last measured_js
        self._latest: dict[str, object] = {}
        self._stale_callbacks: list[StaleCallback] = [on_stale] if on_stale else []
        self._stale_fired = False
        self.stale_events = 0
        self.received = 0
        self.malformed = 0  # measured_js messages whose bytes were not a JointState (dropped)
        self.topic = {k: f"{self.namespace}/{k}" for k in
                      ("measured_js", "setpoint_js", "measured_cp", "local/measured_cp",
                       "body/measured_cf", "servo_jp", "servo_jf", "move_jp", "operating_state",
                       "state_command", "error")}
        # operating state: the newest, how many came, the index of the newest busy and
        # idle ones (move_jp's wait), and the arm's newest error message
        self._state: OperatingState | None = None
        self._state_count = 0
        self.state_answers = 0  #: answers of its operating_state service (confirm_state waits on one)
        self._busy_index = 0
        self._idle_index = 0
        self._error: tuple[float, str] | None = None  # (time_base.now(), text)
        self._in_control = False  # ready() succeeded: leaving ENABLED and homed is a fault
        self._fault: OperatingState | None = None
        self._fault_error: ArmFault | None = None
        #: how the last move_jp(wait=True) waited: "busy" (operating_state) or "position"
        self.move_wait: str | None = None
        self.move_end: str | None = None
        self.states_error: str | None = None  # why states are not read, if they are not
        self._command_qos = None
        # the whole arm: where joints 1-3 are in its messages, how many it has, the wrist
        self._index: tuple[int, ...] | None = None
        self._names: tuple[str, ...] = ()
        self.joint_count = 3
        self._full: tuple[np.ndarray, np.ndarray] | None = None  # all joints' (q, dq), newest
        self.wrist_hold: np.ndarray | None = None
        self._state_client = None
        self._state_command = None  # its publisher, on the control node
        self._control_subs: list = []  # operating_state and error, on the control node
        self._impedance_type = None
        self._stamps: deque[float] = deque(maxlen=64)  # header stamps of the newest measured_js
        self._console = console if console == "auto" else "/" + console.strip("/")
        if self._console != "auto":
            self._set_console(self._console)

        # Best effort matches both reliable (the dVRK's default) and best-effort publishers,
        # and never lets a slow reader hold up a 1 kHz stream with retransmissions.
        sensor_qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.BEST_EFFORT)
        command_qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE)
        t = self.topic
        store = {"setpoint_js": (JointStateMsg, lambda m: self._model_joints(self._joint_state(m))),
                 "measured_cp": (PoseStamped, self._pose),
                 "local/measured_cp": (PoseStamped, self._pose), "body/measured_cf": (WrenchStamped, self._wrench)}
        unknown = set(streams) - set(ALL_STREAMS)
        if unknown:
            raise ValueError(f"unknown arm streams {sorted(unknown)}; known: {', '.join(ALL_STREAMS)}")
        self.streams = ("measured_js",) + tuple(k for k in streams if k != "measured_js")
        # raw: measured_js comes at 500 Hz-1 kHz per arm; its bytes are read here (drivers.cdr,
        # 2 us) rather than made into an rclpy message object (29 us)
        self._subs = [node.create_subscription(JointStateMsg, t["measured_js"], self._on_measured_js, sensor_qos,
                                               raw=True)]
        for key in self.streams[1:]:
            msg_type, convert = store[key]
            self._subs.append(node.create_subscription(
                msg_type, t[key], lambda m, key=key, convert=convert: self._store(key, convert(m)), sensor_qos))
        self._pubs = {k: node.create_publisher(JointStateMsg, t[k], command_qos)
                      for k in ("servo_jp", "servo_jf", "move_jp")}
        self._StringStamped = None
        if states:
            try:
                from crtk_msgs.msg import OperatingState as OperatingStateMsg, StringStamped
            except ImportError as exc:  # a platform the shipped messages were not built for
                self.states_error = str(exc).splitlines()[0]
            else:
                self._StringStamped = StringStamped
                control = self.control_node
                self._control_subs = [
                    control.create_subscription(OperatingStateMsg, t["operating_state"], self._on_operating_state,
                                                sensor_qos),
                    control.create_subscription(String, t["error"], self._on_error, sensor_qos)]
                self._state_command = control.create_publisher(StringStamped, t["state_command"], command_qos)
                try:
                    from crtk_msgs.msg import CartesianImpedance
                    from crtk_msgs.srv import TriggerOperatingState
                except ImportError:
                    pass
                else:
                    self._state_client = control.create_client(TriggerOperatingState, t["operating_state"])
                    # made with the others, so that discovery has matched it before a first servo_ci
                    self._impedance_type = CartesianImpedance
                    self._pubs["servo_ci"] = node.create_publisher(CartesianImpedance, f"{self.namespace}/servo_ci",
                                                                   command_qos)
        else:
            self.states_error = "states=False"
        self._command_qos = command_qos
        if self._console != "auto":
            self._console_publishers()

        self._closing = threading.Event()
        self._executor = None
        self._spin_thread = None
        if spin:
            from rclpy.executors import SingleThreadedExecutor

            self._executor = SingleThreadedExecutor(context=node.context)
            self._executor.add_node(node)
            if self.control_node is not node:
                self._executor.add_node(self.control_node)
            self._spin_thread = threading.Thread(target=self._spin, name=f"ros-{self.name}", daemon=True)
            self._spin_thread.start()
        self._watchdog_thread = threading.Thread(target=self._watch, name=f"watchdog-{self.name}", daemon=True)
        self._watchdog_thread.start()

    # -- executor thread ----------------------------------------------------------------
    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - context shut down under us while closing
            if not self._closing.is_set():
                raise

    @staticmethod
    def _joint_state(m) -> JointState:
        return JointState(_stamp_seconds(m.header), np.array(m.position, float), np.array(m.velocity, float),
                          np.array(m.effort, float), tuple(m.name))

    @staticmethod
    def _pose(m) -> Pose:
        p, o = m.pose.position, m.pose.orientation
        # geometry_msgs/Quaternion is (x, y, z, w), scalar last.
        R = quat_xyzw_to_matrix(np.array([o.x, o.y, o.z, o.w], float))
        return Pose(_stamp_seconds(m.header), np.array([p.x, p.y, p.z]), R, m.header.frame_id)

    @staticmethod
    def _wrench(m) -> Wrench:
        f, tq = m.wrench.force, m.wrench.torque
        return Wrench(_stamp_seconds(m.header), np.array([f.x, f.y, f.z]), np.array([tq.x, tq.y, tq.z]),
                      m.header.frame_id)

    def _map(self, names: tuple[str, ...], n: int) -> tuple[int, ...]:
        """Indices of joints 1-3 in a message with `names` (n values), found once per naming."""
        if names != self._names or self._index is None:
            index = []
            for options in _MODEL_JOINTS:
                found = next((names.index(o) for o in options if o in names), None)
                index.append(found)
            if None in index:
                index = list(range(min(3, n)))  # no names, or other ones: by position
            self._index, self._names = tuple(index), names
            self.joint_count = n
        return self._index

    def _model_joints(self, full: JointState) -> JointState:
        """Joints 1-3 of a message of the whole arm (found by name, see the module docstring)."""
        n = len(full.position)
        idx = self._map(full.name, n)
        if n <= 3 and idx == (0, 1, 2):
            return full

        def pick(v):
            return v[list(idx)] if len(v) == n else v[:3]
        return JointState(full.t, pick(full.position), pick(full.velocity), pick(full.effort),
                          tuple(full.name[i] for i in idx) if full.name else ())

    def _on_measured_js(self, raw: bytes) -> None:
        try:
            t_ns, _, names, position, velocity, effort = cdr.joint_state(raw)
        except cdr.CdrError:
            with self._lock:
                self.malformed += 1
            return
        full = JointState(t_ns * 1e-9, np.array(position, float), np.array(velocity, float),
                          np.array(effort, float), names)
        js = self._model_joints(full)
        with self._cond:
            self._stamps.append(full.t)
            self._full = (full.position, full.velocity)
            self._js = js
            self._js_log.append(js)
            self._js_rx = self._time.now()
            self._stale_fired = False
            self.received += 1
            self._cond.notify_all()
        self._time.notify()

    def _store(self, key: str, value) -> None:
        with self._lock:
            self._latest[key] = value

    def _on_operating_state(self, m) -> None:
        st = OperatingState(_stamp_seconds(m.header), str(m.state), bool(m.is_homed), bool(m.is_busy))
        with self._cond:
            self._state = st
            self._state_count += 1
            if st.is_busy:
                self._busy_index = self._state_count
            else:
                self._idle_index = self._state_count
            if self._in_control and self._fault is None and not st.ready:
                self._fault = st
            self._cond.notify_all()

    def _on_error(self, m) -> None:
        with self._cond:
            self._error = (self._time.now(), str(m.data))
            self._cond.notify_all()

    # -- watchdog thread ----------------------------------------------------------------
    def _watch(self) -> None:
        while not self._closing.wait(self.watchdog / 5.0):
            with self._lock:
                rx, fired, js = self._js_rx, self._stale_fired, self._js
            if rx is None or fired:
                continue  # not armed before the first sample; once per outage
            age = self._age(rx)
            err = self._time.stalled()  # on simulated time: the clock itself stopped
            if age <= self.watchdog and err is None:
                continue
            with self._lock:
                self._stale_fired = True
            self.stale_events += 1
            err = err or self._stale(age)
            try:
                with self._lock:
                    full = self._full
                self._publish("servo_jp", position=full[0] if full is not None else js.position)
            except Exception:  # noqa: BLE001 - a dead context must not stop the callbacks
                pass
            for cb in list(self._stale_callbacks):
                try:
                    cb(err)
                except Exception as exc:  # noqa: BLE001 - report, and still call the others
                    self.node.get_logger().error(f"{self.name}: stale callback failed: {exc}")

    def _stale(self, age: float) -> StaleStream:
        """The StaleStream of measured_js `age` s old: with the rate the arm had been
        publishing at and the rig.toml key of the watchdog."""
        return StaleStream(self.topic["measured_js"], age, self.watchdog, rate_hz=self.published_rate(),
                           setting=self.setting)

    def _age(self, rx: float) -> float:
        """Seconds the executor has been looking for measured_js since the last one came (on
        simulated time: simulated seconds since it came, which a starved process never adds)."""
        now = self._time.now()
        if self._polled is not None and not self._time.simulated:
            now = min(now, self._polled())
        return max(0.0, now - rx)

    def add_stale_callback(self, fn: StaleCallback) -> None:
        """Call `fn(StaleStream)` from the watchdog thread when measured_js goes stale."""
        self._stale_callbacks.append(fn)

    # -- reading ------------------------------------------------------------------------
    def published_rate(self) -> float:
        """Hz at which the arm publishes measured_js, from the header stamps of the newest
        messages (the median interval): what the console sends, whatever delays this
        process's reading of them (0.0 before two messages)."""
        with self._lock:
            t = np.array(self._stamps)
        d = np.diff(t)
        d = d[d > 0]
        return float(1.0 / np.median(d)) if d.size else 0.0

    def stream_age(self) -> float:
        """Seconds since the last measured_js (inf before the first)."""
        with self._lock:
            rx = self._js_rx
        return float("inf") if rx is None else self._age(rx)

    def wait_for_data(self, timeout: float = 5.0) -> bool:
        """Block until a measured_js arrived (True) or `timeout` s passed (False)."""
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self._js is None:
                left = deadline - tb.now()
                if left <= 0:
                    return False
                tb.wait(self._cond, left)
        return True

    def wait_newer(self, count: int, timeout: float) -> bool:
        """Block until more than `count` measured_js have arrived (True) or `timeout` s passed."""
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self.received <= count:
                left = deadline - tb.now()
                if left <= 0:
                    return False
                tb.wait(self._cond, left)
        return True

    def last_stamp(self) -> float:
        """The header stamp (s) of the newest measured_js (-inf before the first)."""
        with self._lock:
            return self._stamps[-1] if self._stamps else float("-inf")

    def measured_js(self) -> JointState:
        """The newest measured joint state, every joint the message carries.

        Raises StaleStream if none arrived within the watchdog interval, ArmFault once the
        arm left ENABLED and homed after `ready()`.
        """
        with self._lock:
            js, rx, fault = self._js, self._js_rx, self._fault
        if fault is not None:
            raise self._fault_raised(fault)
        self._time.check()
        age = float("inf") if rx is None else self._age(rx)
        if js is None or age > self.watchdog:
            raise self._stale(age)
        return js

    def drain_js(self) -> list[JointState]:
        """Every measured_js received since the last drain, oldest first (the newest 4096 at
        most); StaleStream and ArmFault as measured_js()."""
        self.measured_js()
        with self._lock:
            out = list(self._js_log)
            self._js_log.clear()
        return out

    def _get(self, key: str):
        if key not in self.streams:
            raise RuntimeError(f"{self.topic[key]}: not subscribed (RosArm streams={self.streams})")
        with self._lock:
            value = self._latest.get(key)
        if value is None:
            raise RuntimeError(f"{self.topic[key]}: no message received yet")
        return value

    def setpoint_js(self) -> JointState:
        return self._get("setpoint_js")

    def measured_cp(self) -> Pose:
        """Newest tool-tip pose (dVRK measured_cp: RCM frame unless a base frame is set)."""
        return self._get("measured_cp")

    def local_measured_cp(self) -> Pose:
        return self._get("local/measured_cp")

    def body_measured_cf(self) -> Wrench:
        return self._get("body/measured_cf")

    # -- commanding ---------------------------------------------------------------------
    def _stamp(self, header) -> None:
        """Stamp a command on this process's ROS clock (simulated time when it follows one)."""
        ns = self._time.now_ns() if self._time.simulated else None
        if ns is None:
            header.stamp = self.node.get_clock().now().to_msg()
        else:
            header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)

    def _send(self, publisher, msg) -> None:
        """Publish a command, counted for the lockstep answers (`drivers.time_base`)."""
        self._time.sent()
        publisher.publish(msg)

    def _publish(self, key: str, position=None, velocity=None, effort=None) -> None:
        m = self._JointState()
        self._stamp(m.header)
        if position is not None:
            m.position = _vector(position, key)
        if velocity is not None:
            m.velocity = _vector(velocity, key)
        if effort is not None:
            m.effort = _vector(effort, key)
        self._send(self._pubs[key], m)

    def _whole(self, values, fill: np.ndarray | None) -> list[float] | None:
        """`values` for joints 1-3 (or the whole arm) as a command of every joint the arm has:
        joints 1-3 at their places, the others from `fill`."""
        if values is None:
            return None
        v = np.asarray(_vector(values, "command"), float)
        with self._lock:
            n, idx = self.joint_count, self._index
        if n <= 3 or v.size >= n or idx is None:
            return v.tolist()
        out = np.zeros(n) if fill is None else np.array(fill, float)
        out[list(idx[:v.size])] = v[:len(idx)]
        return out.tolist()

    def _wrist_fill(self) -> np.ndarray | None:
        """Every joint's hold position: the newest measured, the wrist at `wrist_hold`."""
        with self._lock:
            full, idx, hold = self._full, self._index, self.wrist_hold
        if full is None or idx is None:
            return None
        q = np.array(full[0], float)
        rest = [i for i in range(len(q)) if i not in idx]
        if hold is not None and len(hold) == len(rest):
            q[rest] = hold
        return q

    def _wrist_effort(self) -> np.ndarray | None:
        """Efforts that hold the wrist at `wrist_hold` (a soft PD), zero on joints 1-3."""
        with self._lock:
            full, idx, hold = self._full, self._index, self.wrist_hold
        if full is None or idx is None:
            return None
        q, dq = np.asarray(full[0], float), np.asarray(full[1], float)
        out = np.zeros(len(q))
        rest = [i for i in range(len(q)) if i not in idx]
        if hold is None or len(hold) != len(rest) or len(dq) != len(q):
            return out
        out[rest] = WRIST_KP * (hold - q[rest]) - WRIST_KD * dq[rest]
        return out

    def servo_jp(self, position, velocity=None) -> None:
        """Joint position set-point (rad, m), with an optional velocity feed-forward; three
        values for joints 1-3 (the wrist held), or the whole arm's."""
        fill = self._wrist_fill()
        self._publish("servo_jp", position=self._whole(position, fill),
                      velocity=self._whole(velocity, None if fill is None else np.zeros(len(fill))))

    def servo_jf(self, effort) -> None:
        """Joint efforts (N m, N) in the JointState effort field; three values for joints
        1-3 (the wrist held by a soft PD), or the whole arm's."""
        self._publish("servo_jf", effort=self._whole(effort, self._wrist_effort()))

    @property
    def supports_servo_ci(self) -> bool:
        """crtk_msgs/CartesianImpedance is available here: `servo_ci` can be sent (whether the
        console takes it is `servo_ci_problem`'s)."""
        return self._impedance_type is not None

    def servo_ci_subscribers(self) -> list[str]:
        """The nodes of the ROS graph, other than this driver's, that subscribe to
        <arm>/servo_ci as crtk_msgs/CartesianImpedance (a dVRK 2.2+ console's bridge does,
        for every arm: cisst-ros' mts_ros_crtk_bridge_provided)."""
        topic = f"{self.namespace}/servo_ci"
        ours = {(n.get_name(), n.get_namespace()) for n in (self.node, self.control_node)}
        return [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in self.node.get_subscriptions_info_by_topic(topic)
                if (i.node_name, i.node_namespace) not in ours and i.topic_type == SERVO_CI_TYPE]

    def servo_ci_problem(self, timeout: float = SERVO_CI_DISCOVERY) -> str | None:
        """None when `servo_ci` reaches the arm: the type loads here and the console
        subscribes to <arm>/servo_ci (asked of the ROS graph for up to `timeout` s of wall
        time: discovery learns a console's subscriptions with its publishers); else one
        line saying which is missing."""
        topic = f"{self.namespace}/servo_ci"
        if self._impedance_type is None:
            return f"{topic}: this Python cannot send it ({self.states_error})"
        deadline = time.monotonic() + timeout
        while not self.servo_ci_subscribers():
            if time.monotonic() > deadline:
                other = [f"{i.node_name} ({i.topic_type})" for i in self.node.get_subscriptions_info_by_topic(topic)
                         if i.topic_type != SERVO_CI_TYPE]
                return (f"{topic}: the console does not subscribe to it"
                        + (f" as {SERVO_CI_TYPE} (subscribed as {', '.join(other)})" if other else
                           " (a dVRK console 2.2 or later bridges it for every arm)"))
            time.sleep(0.05)
        return None

    def measured_arm(self) -> tuple[np.ndarray, np.ndarray]:
        """The newest measured positions and velocities of the whole arm in the dVRK's order
        (joints 1-3, then the others as the message carries them: the wrist), for the
        PSM-with-tool kinematics (`rig.model.psm_arm_kinematics`). StaleStream and ArmFault as
        measured_js()."""
        js = self.measured_js()
        with self._lock:
            full, idx = self._full, self._index
        if full is None or idx is None:
            return np.asarray(js.position, float), np.asarray(js.velocity, float)
        q, dq = np.asarray(full[0], float), np.asarray(full[1], float)
        order = list(idx) + [i for i in range(len(q)) if i not in idx]
        return q[order], (dq[order] if len(dq) == len(q) else np.zeros(len(q)))

    def servo_ci(self, position, orientation=None, stiffness=(0.0, 0.0, 0.0), damping=(0.0, 0.0, 0.0),
                 bias=(0.0, 0.0, 0.0), deadband=(0.0, 0.0, 0.0), torque_stiffness=(0.0, 0.0, 0.0),
                 torque_damping=(0.0, 0.0, 0.0), force_orientation=None, torque_bias=(0.0, 0.0, 0.0)) -> None:
        """The arm's Cartesian impedance about the tool-tip goal `position` (m, 3) and
        `orientation` (3x3, the torque frame; default identity), in the frame of measured_cp,
        run by the dVRK in its servo loop (crtk_msgs/CartesianImpedance on <arm>/servo_ci):
        per axis of `force_orientation` (3x3, its columns the axes in the base frame;
        default the base frame's) a spring `stiffness` (N/m, >= 0), damper `damping`
        (N s/m), `bias` (N) and `deadband` (m); the orientation's `torque_stiffness`
        (N m/rad), `torque_damping` and `torque_bias` (N m, on the axes of `orientation`). The same gains on both half-planes. The dVRK's
        controller adds p * (pose - goal): the stiffness and damping are sent negated, as
        its own examples do."""
        if self._impedance_type is None:
            raise RuntimeError(f"{self.namespace}/servo_ci: crtk_msgs are not available ({self.states_error})")
        m = impedance_message(self._impedance_type(), position, orientation, stiffness, damping, bias, deadband,
                              torque_stiffness, torque_damping, force_orientation, torque_bias)
        self._stamp(m.header)
        self._send(self._pubs["servo_ci"], m)

    def use_gravity_compensation(self, on: bool) -> None:
        """Ask the arm to add its model's gravity torque to effort commands (servo_jf,
        servo_cf, servo_ci), as the dVRK's feed-forward."""
        from std_msgs.msg import Bool

        if "use_gravity_compensation" not in self._pubs:
            self._pubs["use_gravity_compensation"] = self.node.create_publisher(
                Bool, f"{self.namespace}/use_gravity_compensation", self._command_qos)
        self._send(self._pubs["use_gravity_compensation"], Bool(data=bool(on)))

    def move_jp(self, position, wait: bool = True, timeout: float = 10.0) -> bool:
        """Start the dVRK's trajectory to `position`; with wait, block until it is done.

        Done, on an arm that publishes operating_state: is_busy rose within BUSY_RISE s of
        the command and fell again (the dVRK's trajectory is over), and the joints given
        are within ARRIVAL_TOLERANCE of the goal (first three; 2e-3 beyond). Without
        operating_state, or when the flag did not rise on an arm that is ENABLED and
        homed: the joints are within ARRIVAL_TOLERANCE of the goal and slower than
        REST_VELOCITY. An arm that is not ENABLED and homed drops the command: False once
        the flag did not rise. False after `timeout` s. Raises StaleStream if measured_js
        stops while waiting, ArmFault if the arm faults. `move_wait` says which of the two
        waits it took ("busy" or "position"), `move_end` how the wait ended: "arrived",
        "dropped" (the arm is not ready: busy never rose) or "timeout".
        """
        goal = np.asarray(_vector(position, "move_jp"))
        with self._lock:
            since = self._state_count
            states = self._state is not None
        self._publish("move_jp", position=self._whole(goal, self._wrist_fill()))
        self.move_wait = self.move_end = None
        if not wait:
            return True
        deadline = self._time.now() + timeout
        if states:
            busy = self._wait_busy(since, deadline)
            if busy is not None:
                self.move_wait = "busy"
                if busy != "fell":
                    self.move_end = busy
                    return False
                # The arm's trajectory is over. Its joints settle on the goal under the PID
                # (joint 3 hovers about the 1 mm tolerance for a while): confirm on them,
                # for what is left of the timeout.
                arrived = self._wait_arrived(goal, deadline, rest=False)
                self.move_end = "arrived" if arrived else "timeout"
                return arrived
        self.move_wait = "position"
        arrived = self._wait_arrived(goal, deadline)
        self.move_end = "arrived" if arrived else "timeout"
        return arrived

    @staticmethod
    def _at(goal: np.ndarray, js: JointState, rest: bool = True) -> bool:
        """The joints given are within ARRIVAL_TOLERANCE (first three; 2e-3 beyond) of
        `goal` and, with `rest`, slower than REST_VELOCITY."""
        n = goal.size
        tol = np.concatenate([ARRIVAL_TOLERANCE, np.full(max(0, n - 3), 2e-3)])[:n]
        rest_v = np.concatenate([REST_VELOCITY, np.full(max(0, n - 3), 0.05)])[:n]
        q, dq = js.position[:n], js.velocity[:n]
        return bool(len(q) == n and np.all(np.abs(q - goal) <= tol)
                    and (not rest or len(dq) < n or np.all(np.abs(dq) <= rest_v)))

    def _wait_busy(self, since: int, deadline: float) -> str | None:
        """Wait for is_busy to rise (an operating_state after index `since` with it set)
        and fall again. "fell"; "timeout": the timeout passed; "dropped": it did not rise
        and the arm is not ready (the command was dropped); None: it did not rise on a
        ready arm (wait on positions instead)."""
        rise_by = min(deadline, self._time.now() + BUSY_RISE)
        rose = None
        while True:
            self.measured_js()  # stale stream or a fault: raise
            with self._cond:
                if rose is None and self._busy_index > since:
                    rose = self._busy_index
                if rose is not None and self._idle_index > rose:
                    return "fell"
                now = self._time.now()
                if rose is None and now >= rise_by:
                    st = self._state
                    return None if (st is not None and st.ready) else "dropped"
                if now >= deadline:
                    return "timeout"
                # wake at least five times per watchdog interval (a stream that stops is
                # then seen within the watchdog plus a fifth of it)
                self._time.wait(self._cond, min((rise_by if rose is None else deadline) - now, self.watchdog / 5.0))

    def _wait_arrived(self, goal: np.ndarray, deadline: float, rest: bool = True) -> bool:
        while True:
            if self._at(goal, self.measured_js(), rest):
                return True
            left = deadline - self._time.now()
            if left <= 0:
                return False
            with self._cond:
                self._time.wait(self._cond, min(left, self.watchdog / 5.0))

    def hold(self) -> None:
        """Hold the last measured position (servo_jp there). Works while merely stale."""
        with self._lock:
            js, full = self._js, self._full
        if js is None:
            raise self._stale(float("inf"))
        self._publish("servo_jp", position=full[0] if full is not None else js.position)

    # -- operating state ----------------------------------------------------------------
    def operating_state(self) -> OperatingState | None:
        """The newest operating_state (None before the first, or when states are not read)."""
        with self._lock:
            return self._state

    def wait_for_state(self, timeout: float) -> bool:
        """Block until an operating_state arrived (True) or `timeout` s passed (False). The
        dVRK publishes it on change only: the arm's operating_state service is asked too."""
        tb = self._time
        deadline = tb.now() + timeout
        asked = -1.0
        with self._cond:
            while self._state is None:
                now = tb.now()
                left = deadline - now
                if left <= 0 or self._StringStamped is None:
                    return False
                if now - asked >= 0.25:
                    asked = now
                    self._cond.release()
                    try:
                        self._ask_state()
                    finally:
                        self._cond.acquire()
                    continue
                tb.wait(self._cond, min(left, 0.05))
        return True

    def confirm_state(self, timeout: float) -> OperatingState | None:
        """Ask the arm's operating_state service and wait up to `timeout` s for its answer;
        the newest state then (None when none came). The dVRK publishes operating_state on
        change only, and an event sent just now may still be on its way: a run that ends on
        another device's fault asks before it says an arm is held."""
        with self._lock:
            asked_after = self.state_answers
        if not self._ask_state():
            return self.operating_state()
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self.state_answers == asked_after:
                left = deadline - tb.now()
                if left <= 0:
                    break
                tb.wait(self._cond, left)
            return self._state

    def _ask_state(self) -> bool:
        """Ask the arm's operating_state service (asynchronously; the answer is taken as an
        operating_state message when it comes). False when there is no service to ask."""
        client = self._state_client
        if client is None or not client.service_is_ready():
            return False
        from crtk_msgs.srv import TriggerOperatingState

        future = client.call_async(TriggerOperatingState.Request())
        future.add_done_callback(self._on_state_answer)
        return True

    def _on_state_answer(self, future) -> None:
        try:
            res = future.result()
        except Exception:  # noqa: BLE001 - the service went away: the topic will tell
            return
        if res is None:
            return
        with self._lock:
            newer = self._state is None or _stamp_seconds(res.operating_state.header) > self._state.t
        if newer:
            self._on_operating_state(res.operating_state)
        with self._cond:
            self.state_answers += 1
            self._cond.notify_all()

    def state_command(self, command: str) -> None:
        """Send one of STATE_COMMANDS on state_command (asynchronous, as on the dVRK)."""
        if command not in STATE_COMMANDS:
            raise ValueError(f"state command must be one of {', '.join(STATE_COMMANDS)}, got {command!r}")
        if self._StringStamped is None:
            raise RuntimeError(f"{self.topic['state_command']}: operating states are off ({self.states_error})")
        m = self._StringStamped()
        self._stamp(m.header)
        m.string = command
        self._send(self._state_command, m)

    def ready(self, timeout: float = 20.0, say=None) -> OperatingState:
        """Enable and home the arm (state_command `enable`, then `home`, each repeated every
        RESEND s while it has not moved on) and wait until it is ENABLED, homed and not
        busy; from then on leaving that state is a fault (see the module docstring).

        An arm in FAULT or PAUSED is left so: that is a person's call at the console.
        Raises ArmFault (one line: the state seen and the arm's last error) on FAULT,
        PAUSED or when `timeout` s pass. `say(line)`, if given, hears each command sent.
        """
        tb = self._time
        deadline = tb.now() + timeout
        with self._lock:
            self._in_control = False
            self._fault = self._fault_error = None
        sent: dict[str, float] = {}
        while True:
            # (no staleness check here: a stall of the controller while it homes is no fault
            # of a run that has not begun; the run's first measured_js() checks it)
            st = self.operating_state()
            if st is not None:
                if st.state in ("FAULT", "PAUSED"):
                    raise self._not_ready(st, f"is {st.state}" + (
                        "; clear the fault at the dVRK console (disable, then re-run)" if st.state == "FAULT"
                        else "; resume it at the dVRK console, then re-run"))
                if st.ready and not st.is_busy:
                    with self._lock:
                        if self._full is not None and self._index is not None:
                            q = np.asarray(self._full[0], float)
                            self.wrist_hold = q[[i for i in range(len(q)) if i not in self._index]].copy()
                        self._in_control = True
                        self._fault = self._fault_error = None
                        if not self._state.ready:  # it changed since
                            self._fault = self._state
                    return st
                want = None
                if st.state == "DISABLED" and not st.is_busy:
                    want = "enable"
                elif st.state == "ENABLED" and not st.is_homed and not st.is_busy:
                    want = "home"
                if want is not None and tb.now() - sent.get(want, -RESEND) >= RESEND:
                    if say is not None and want not in sent:
                        say(f"{self.name}: {want}")
                    self.state_command(want)
                    sent[want] = tb.now()
            elif tb.now() - sent.get("ask", -RESEND) >= 0.25:
                self._ask_state()  # events only: ask what the state is
                sent["ask"] = tb.now()
            now = tb.now()
            if now >= deadline:
                raise self._not_ready(st, f"not ENABLED and homed within {timeout:g} s"
                                      + ("" if st is None else f" ({st.describe()})")
                                      + "; check the dVRK console (power, e-stop, homing) or `rig sim`")
            with self._cond:
                tb.wait(self._cond, min(deadline - now, 0.05))

    def _last_error(self, within: float = 2.0, locked: bool = False) -> str:
        """The arm's newest error message if it came within `within` s, else ""."""
        if locked:  # the caller holds the lock
            err = self._error
        else:
            with self._lock:
                err = self._error
        return err[1] if err is not None and self._time.now() - err[0] <= within else ""

    def _not_ready(self, st: OperatingState | None, what: str) -> ArmFault:
        error = self._last_error()
        seen = "no operating_state received" if st is None else ""
        text = f"{self.topic['operating_state']}: {self.name} {what}"
        if seen:
            text += f" ({seen})"
        if error:
            text += f"; its last error: {error}"
        return ArmFault(text, self.topic["operating_state"], st, error)

    def _fault_raised(self, st: OperatingState) -> ArmFault:
        """The ArmFault for a run whose arm left ENABLED and homed (composed once)."""
        if self._fault_error is not None:
            return self._fault_error
        if st.state == "FAULT":  # its error message may come just after the state
            tb = self._time
            until = tb.now() + 0.25
            with self._cond:
                while not self._last_error(locked=True) and tb.now() < until:
                    tb.wait(self._cond, until - tb.now())
        error = self._last_error()
        what = {"FAULT": "went to FAULT", "DISABLED": "was disabled", "PAUSED": "was paused"}.get(
            st.state, f"went to {st.state}") if st.state != "ENABLED" else "was unhomed"
        text = (f"{self.topic['operating_state']}: {self.name} {what} during the run ({st.describe()})"
                + (f": {error}" if error else "") + "; it no longer obeys commands. Check the arm at the dVRK "
                "console (or `rig sim`), then re-run")
        self._fault_error = ArmFault(text, self.topic["operating_state"], st, error)
        return self._fault_error

    # -- console ------------------------------------------------------------------------
    def _set_console(self, namespace: str) -> None:
        self._console = namespace
        self.topic["power_on"] = f"{namespace}/power_on"
        self.topic["home"] = f"{namespace}/home"

    def _console_publishers(self) -> None:
        for key in ("power_on", "home"):
            self._pubs[key] = self.node.create_publisher(self._Empty, self.topic[key], self._command_qos)

    def console_namespace(self) -> str:
        """The console's namespace; with console="auto", found from the ROS graph: "/system"
        when /system/power_on exists (dVRK 2.4), "/console" when /console/power_on does
        (2.3), and "/console" if neither shows within 2 s."""
        if self._console == "auto":
            # the graph fills in as discovery goes on: look for up to 2 s
            found, deadline = None, time.monotonic() + 2.0
            while found is None and time.monotonic() < deadline:
                names = [n for n, _ in self.node.get_topic_names_and_types()]
                # the power topic itself: a 2.4 system has /console/teleop/... too
                found = next((ns for ns in ("/system", "/console") if f"{ns}/power_on" in names), None)
                if found is None:
                    time.sleep(0.05)
            self._set_console(found or "/console")
            self._console_publishers()
        return self._console

    def power_on(self) -> None:
        self.console_namespace()
        self._send(self._pubs["power_on"], self._Empty())

    def home(self) -> None:
        """Ask the console to home the arms (asynchronous, as on the dVRK)."""
        self.console_namespace()
        self._send(self._pubs["home"], self._Empty())

    def wait_for_subscribers(self, timeout: float = 5.0) -> bool:
        """Block until every command topic has a subscriber (the controller is there);
        servo_ci not counted (a dVRK before 2.2 has none)."""
        deadline = time.monotonic() + timeout
        while any(p.get_subscription_count() == 0 for k, p in self._pubs.items() if k != "servo_ci"):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def close(self) -> None:
        """Stop the watchdog and executor threads and destroy this driver's endpoints."""
        if self._closing.is_set():
            return
        self._closing.set()
        self._watchdog_thread.join(timeout=5.0)
        if self._executor is not None:
            # endpoints destroyed under a spinning executor crash the process: on a loaded
            # machine the spin thread may take more than a second to notice the shutdown
            self._executor.shutdown(timeout_sec=5.0)
            self._spin_thread.join(timeout=5.0)
            if self._spin_thread.is_alive():
                return  # still in the executor: its endpoints are left to the process's end
        for s in self._subs:
            self.node.destroy_subscription(s)
        for s in self._control_subs:
            self.control_node.destroy_subscription(s)
        if self._state_client is not None:
            self.control_node.destroy_client(self._state_client)
            self._state_client = None
        if self._state_command is not None:
            self.control_node.destroy_publisher(self._state_command)
            self._state_command = None
        for p in self._pubs.values():
            self.node.destroy_publisher(p)
        self._subs, self._pubs, self._control_subs = [], {}, []
