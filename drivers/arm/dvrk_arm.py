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

Threading model. The driver is given a node (docs/fakes.md, "A driver gets its transport") and never creates one. Its
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

from drivers.arm.crtk import ARRIVAL_TOLERANCE, REST_VELOCITY, ArmFault, OperatingState
from drivers.arm.dvrk_arm_state import ArmOperatingState
from drivers.arm.dvrk_arm_streams import ArmStreams, StaleCallback
from drivers.interfaces import JointState


#: s within which a move_jp's is_busy must rise before the wait falls back to positions
#: (the command crosses the wire and waits for the arm's next cycle; a dVRK raises it
#: within a cycle or two). On the wall clock a starved `rig sim` raised it later than that
#: under the test suite's load: the wait then falls back to positions, which is no fault.
BUSY_RISE = 0.5

#: N m/rad and N m s/rad of the wrist's hold under servo_jf: soft enough to be stable at a
#: 100 Hz command rate on the wrist's ~1e-5 kg m^2 (kd T / I < 1), enough to keep the tool
#: from drifting on its own friction
WRIST_KP = 0.2
WRIST_KD = 0.0005

#: the ROS type of <arm>/servo_ci, and the s of wall time a console's subscription to it is
#: looked for in the ROS graph (its endpoints are discovered together with its publishers,
#: already heard when this is asked: the wait covers a discovery still in flight)
SERVO_CI_TYPE = "crtk_msgs/msg/CartesianImpedance"
SERVO_CI_DISCOVERY = 2.0

#: the arm's state topics RosArm can subscribe (measured_js is always subscribed)
ALL_STREAMS = ("measured_js", "setpoint_js", "measured_cp", "local/measured_cp", "body/measured_cf")


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
    from drivers.common.quaternion import matrix_to_quat_xyzw

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


class RosArm(ArmStreams, ArmOperatingState):
    """Arm protocol over the dVRK CRTK ROS 2 topics (see the module docstring).

    node: an rclpy Node; namespace: the arm's topic namespace ("/PSM1"); watchdog: s of
    measured_js silence before the stream is stale; spin: run an executor thread for the
    node here; on_stale: callback(StaleStream) fired from the watchdog thread once per
    outage (more with `add_stale_callback`); console: the console's namespace
    ("/console", "/system", or "auto": the one the running system shows in the ROS graph);
    streams: which of `ALL_STREAMS` to subscribe (measured_js always: every fewer topic is
    less work for the executor); polled: the monotonic time at which the executor last
    looked for messages (`drivers.common.ros_session.RosSession.executor_time`): the staleness age is
    counted up to then, so that a starved process never takes a healthy stream for a stale
    one (None: up to now, for an executor that is never starved); states: read
    operating_state and send state_command (False: neither, as on a controller without
    the CRTK state machine); setting: the rig.toml key of `watchdog`, named by a stale
    stream's line (default `[arms.<name>] watchdog`, the name from the namespace);
    control_node: the node of the operating_state and error events, the operating_state
    service and state_command (`drivers.common.ros_session.RosSession.control`: they must not
    queue behind the streams; default `node`); time_base: the clock every wait, timeout
    and stream age is on (`drivers.common.time_base`: the wall clock by default, or a simulator's
    /clock in lockstep, whose waits free the world and whose commands are counted).
    """

    def __init__(self, node, namespace: str, watchdog: float = 0.05, *, spin: bool = True,
                 on_stale: StaleCallback | None = None, console: str = "/console", qos_depth: int = 10,
                 streams: tuple[str, ...] = ALL_STREAMS, polled: Callable[[], float] | None = None,
                 states: bool = True, setting: str | None = None, control_node=None, time_base=None):
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState as JointStateMsg
        from std_msgs.msg import Empty

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
        from drivers.common.time_base import WallTime

        self._time = time_base if time_base is not None else WallTime()
        self._JointState = JointStateMsg
        self._Empty = Empty
        self._init_readings()
        if on_stale:
            self._stale_callbacks.append(on_stale)
        self._console = console if console == "auto" else "/" + console.strip("/")
        if self._console != "auto":
            self._set_console(self._console)

        # Best effort matches both reliable (the dVRK's default) and best-effort publishers,
        # and never lets a slow reader hold up a 1 kHz stream with retransmissions.
        sensor_qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.BEST_EFFORT)
        command_qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE)
        self._subscribe_streams(streams, sensor_qos, command_qos)
        self._StringStamped = None
        if states:
            self._connect_states(sensor_qos, command_qos)
        else:
            self.states_error = "states=False"
        self._command_qos = command_qos
        if self._console != "auto":
            self._console_publishers()
        self._start_threads(spin)

    def _init_readings(self) -> None:
        """What the arm has heard (nothing yet): its streams, operating state, faults, counters."""
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        # every measured_js since the last drain_js() (a few seconds at the dVRK's rates)
        self._js_log: deque[JointState] = deque(maxlen=4096)
        self._js: JointState | None = None
        self._js_rx: float | None = None  # time_base.now() of the last measured_js
        self._latest: dict[str, object] = {}
        self._stale_callbacks: list[StaleCallback] = []
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

    def _subscribe_streams(self, streams: tuple[str, ...], sensor_qos, command_qos) -> None:
        """Subscribe measured_js and the other `streams`; the joint command publishers."""
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from sensor_msgs.msg import JointState as JointStateMsg

        node, t = self.node, self.topic
        store = {"setpoint_js": (JointStateMsg, lambda m: self._model_joints(self._joint_state(m))),
                 "measured_cp": (PoseStamped, self._pose),
                 "local/measured_cp": (PoseStamped, self._pose), "body/measured_cf": (WrenchStamped, self._wrench)}
        unknown = set(streams) - set(ALL_STREAMS)
        if unknown:
            raise ValueError(f"unknown arm streams {sorted(unknown)}; known: {', '.join(ALL_STREAMS)}")
        self.streams = ("measured_js",) + tuple(k for k in streams if k != "measured_js")
        # raw: measured_js comes at 500 Hz-1 kHz per arm; its bytes are read here (drivers.common.cdr,
        # 2 us) rather than made into an rclpy message object (29 us)
        self._subs = [node.create_subscription(JointStateMsg, t["measured_js"], self._on_measured_js, sensor_qos,
                                               raw=True)]
        for key in self.streams[1:]:
            msg_type, convert = store[key]
            self._subs.append(node.create_subscription(
                msg_type, t[key], lambda m, key=key, convert=convert: self._store(key, convert(m)), sensor_qos))
        self._pubs = {k: node.create_publisher(JointStateMsg, t[k], command_qos)
                      for k in ("servo_jp", "servo_jf", "move_jp")}

    def _connect_states(self, sensor_qos, command_qos) -> None:
        """The operating state, error and state commands on the control node, and servo_ci,
        where the CRTK messages load (else `states_error` says why not)."""
        from std_msgs.msg import String

        node, t = self.node, self.topic
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

    def _start_threads(self, spin: bool) -> None:
        """The executor spinning the nodes (`spin`: else someone else spins them) and the watchdog."""
        node = self.node
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

    # -- commanding ---------------------------------------------------------------------
    def _stamp(self, header) -> None:
        """Stamp a command on this process's ROS clock (simulated time when it follows one)."""
        ns = self._time.now_ns() if self._time.simulated else None
        if ns is None:
            header.stamp = self.node.get_clock().now().to_msg()
        else:
            header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)

    def _send(self, publisher, msg) -> None:
        """Publish a command, counted for the lockstep answers (`drivers.common.time_base`)."""
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
