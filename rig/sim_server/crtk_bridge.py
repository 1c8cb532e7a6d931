"""The CRTK ROS 2 interface of one served dVRK PSM: its topics, services and events, as the dVRK bridges them.

`ArmBridge` puts a `drivers.arm.fake_psm.FakePSM` and its operating state
(`drivers.arm.fake_arm_state.FakeArmState`) on the topics that jhu-cisst/cisst-ros's CRTK bridge
(`mts_ros_crtk_bridge_provided.cpp`) gives a dVRK 2.4 PSM under /<arm>:

* published every ROS period while someone subscribes (and only then built), as CDR bytes
  written straight from the arm's arrays (`drivers.common.cdr`): measured_js, setpoint_js,
  measured_cp, setpoint_cp, local/measured_cp, local/setpoint_cp, measured_cv,
  local/measured_cv, body/measured_cf, spatial/measured_cf, body/jacobian,
  spatial/jacobian (std_msgs/Float64MultiArray, 6 x 6, row major), jaw/measured_js,
  jaw/setpoint_js;
* published as events (on change only, as the dVRK's events bridge): operating_state,
  error, warning, status, goal_reached, trajectory_j/ratio (and ratio_v, ratio_a);
* subscribed: servo_jp, servo_jr, move_jp, move_jr, servo_jf (sensor_msgs/JointState),
  servo_cp, move_cp (PoseStamped), body/servo_cf, spatial/servo_cf (WrenchStamped),
  servo_ci (crtk_msgs/CartesianImpedance), hold, free (Empty), state_command,
  use_gravity_compensation, body/set_cf_orientation_absolute, emulate_tool_present (Bool),
  trajectory_j/set_ratio (Float64), jaw/servo_jp, jaw/move_jp, jaw/servo_jf;
* services: forward_kinematics, local/forward_kinematics, inverse_kinematics
  (crtk_msgs Query*Kinematics) and operating_state (crtk_msgs/TriggerOperatingState).

Subscriptions only queue (the server applies them on its main thread, the world's only
writer); services answer from the executor thread with kinematics alone. Publishers use
the dVRK's default QoS (reliable, volatile, depth 10). Which streams have a subscriber is
looked up by the server (`refresh_watched`) and learnt at once from each publisher's
matched event, so a client that subscribes late gets its first sample at the next period.
"""

from __future__ import annotations

import numpy as np

from drivers.common import cdr

#: topics published every ROS period (while subscribed)
STREAMS = ("measured_js", "setpoint_js", "measured_cp", "setpoint_cp", "local/measured_cp", "local/setpoint_cp",
           "measured_cv", "local/measured_cv", "body/measured_cf", "spatial/measured_cf", "body/jacobian",
           "spatial/jacobian", "jaw/measured_js", "jaw/setpoint_js")
#: commands that count as motion (they pass the arm's operating state and its stamp order)
MOTION = ("servo_jp", "servo_jr", "move_jp", "move_jr", "servo_cp", "move_cp", "servo_jf", "body/servo_cf",
          "spatial/servo_cf", "servo_ci", "hold", "free", "jaw/servo_jp", "jaw/move_jp", "jaw/servo_jf")
_SETPOINTS = frozenset({"setpoint_js", "jaw/setpoint_js", "setpoint_cp", "local/setpoint_cp"})
#: the layout of the published Jacobians (std_msgs/MultiArrayLayout dim: label, size, stride)
JACOBIAN_DIMS = (("rows", 6, 36), ("columns", 6, 6))
#: of those, the ones that start a trajectory (busy until its end)
MOVES = ("move_jp", "move_jr", "move_cp", "jaw/move_jp")


def pose_to_matrix(pose) -> np.ndarray:
    from drivers.common.quaternion import quat_xyzw_to_matrix

    o, p = pose.orientation, pose.position
    T = np.eye(4)
    T[:3, :3] = quat_xyzw_to_matrix(np.array([o.x, o.y, o.z, o.w], float))
    T[:3, 3] = (p.x, p.y, p.z)
    return T


def matrix_to_pose(T: np.ndarray, pose) -> None:
    from drivers.common.quaternion import matrix_to_quat_xyzw

    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in T[:3, 3])
    o = pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in matrix_to_quat_xyzw(T[:3, :3]))


def _quat(T: np.ndarray) -> list[float]:
    """(qx, qy, qz, qw) of a 4x4 pose's rotation, w >= 0."""
    from drivers.common.quaternion import matrix_to_quat_xyzw

    return matrix_to_quat_xyzw(T[:3, :3]).tolist()


def _turned(a: list[float], b: list[float]) -> list[float]:
    """The Hamilton product a b of two unit quaternions (x, y, z, w), w >= 0 (as `_quat`)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    q = [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
         aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]
    return [-v for v in q] if q[3] < 0 else q


def _quat_matrix(q) -> np.ndarray:
    from drivers.common.quaternion import quat_xyzw_to_matrix

    v = np.array([q.x, q.y, q.z, q.w], float)
    if not np.any(v):  # an all-zero quaternion (a message left at its defaults): identity
        return np.eye(3)
    return quat_xyzw_to_matrix(v / np.linalg.norm(v))


def impedance_from_msg(m):
    """A crtk_msgs/CartesianImpedance as `drivers.arm.fake_psm.Impedance`."""
    from drivers.arm.fake_psm import Impedance

    def gains(g):
        return tuple(np.array([v.x, v.y, v.z], float) for v in (g.p, g.d, g.bias, g.deadband))

    p = m.force_position
    return Impedance([p.x, p.y, p.z], _quat_matrix(m.force_orientation), _quat_matrix(m.torque_orientation),
                     {"position_positive": gains(m.position_positive),
                      "position_negative": gains(m.position_negative),
                      "orientation_positive": gains(m.orientation_positive),
                      "orientation_negative": gains(m.orientation_negative)})


class ArmBridge:
    """One served PSM's CRTK topics on `node` (see the module docstring).

    psm: the `FakePSM`; state: its `FakeArmState`; queue(fn, key, msg): how a received
    command reaches the main thread; stamp_ns(t): the header stamp (ns) of a sample at sim
    time t; event_stamp_ns(): the header stamp (ns) of an event published now (strictly
    increasing); servo_ci: subscribe to it, as a dVRK 2.2+ console's bridge does (False: a
    bridge without it). `published` counts the ROS periods served (the streams due, published to
    whoever listened); `sent` the messages of each stream.
    """

    def __init__(self, node, psm, state, queue, stamp_ns, event_stamp_ns, servo_ci: bool = True):
        from crtk_msgs.msg import CartesianImpedance, OperatingState, StringStamped
        from crtk_msgs.srv import QueryForwardKinematics, QueryInverseKinematics, TriggerOperatingState
        from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
        from rclpy.event_handler import PublisherEventCallbacks
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Empty, Float64, Float64MultiArray, String

        self.node, self.psm, self.state = node, psm, state
        self.name = psm.name
        self._stamp_ns, self._event_stamp_ns = stamp_ns, event_stamp_ns
        self._T = {"state": OperatingState, "string": String, "bool": Bool, "float": Float64}
        qos = QoSProfile(depth=10)
        ns = "/" + self.name
        types = {"measured_js": JointState, "setpoint_js": JointState, "jaw/measured_js": JointState,
                 "jaw/setpoint_js": JointState, "measured_cv": TwistStamped, "local/measured_cv": TwistStamped,
                 "body/measured_cf": WrenchStamped, "spatial/measured_cf": WrenchStamped,
                 "body/jacobian": Float64MultiArray, "spatial/jacobian": Float64MultiArray}
        self.watched: frozenset[str] = frozenset()
        self.pub = {k: node.create_publisher(types.get(k, PoseStamped), f"{ns}/{k}", qos,
                                             event_callbacks=PublisherEventCallbacks(
                                                 matched=lambda info, k=k: self._matched(k, info.current_count)))
                    for k in STREAMS}
        events = {"operating_state": OperatingState, "error": String, "warning": String, "status": String,
                  "goal_reached": Bool, "trajectory_j/ratio": Float64, "trajectory_j/ratio_v": Float64,
                  "trajectory_j/ratio_a": Float64}
        self.event_pub = {k: node.create_publisher(t, f"{ns}/{k}", qos) for k, t in events.items()}
        subs = {"servo_jp": JointState, "servo_jr": JointState, "move_jp": JointState, "move_jr": JointState,
                "servo_jf": JointState, "servo_cp": PoseStamped, "move_cp": PoseStamped,
                "body/servo_cf": WrenchStamped, "spatial/servo_cf": WrenchStamped, "servo_ci": CartesianImpedance,
                "hold": Empty, "free": Empty, "state_command": StringStamped, "use_gravity_compensation": Bool,
                "body/set_cf_orientation_absolute": Bool, "emulate_tool_present": Bool,
                "trajectory_j/set_ratio": Float64, "jaw/servo_jp": JointState, "jaw/move_jp": JointState,
                "jaw/servo_jf": JointState}
        if not servo_ci:  # a console whose bridge does not take it (`rig sim --no-servo-ci`)
            del subs["servo_ci"]
        self.subs = [node.create_subscription(t, f"{ns}/{k}", queue(self.apply, k), qos) for k, t in subs.items()]
        self.services = [
            node.create_service(QueryForwardKinematics, f"{ns}/forward_kinematics", self._fk),
            node.create_service(QueryForwardKinematics, f"{ns}/local/forward_kinematics",
                                lambda req, res: self._fk(req, res, local=True)),
            node.create_service(QueryInverseKinematics, f"{ns}/inverse_kinematics", self._ik),
            node.create_service(TriggerOperatingState, f"{ns}/operating_state", self._trigger_state),
        ]
        self._names = tuple(psm.joint_names)
        self._base = None  # (base frame, its quaternion)
        self.published = 0
        self.sent = dict.fromkeys(STREAMS, 0)

    # -- services (executor thread: kinematics only) -------------------------------------
    def _fk(self, req, res, local: bool = False):
        try:
            T = self.psm.forward_kinematics(np.asarray(req.jp, float), local=local)
        except ValueError as exc:
            res.result, res.message = False, str(exc)
            return res
        matrix_to_pose(T, res.cp)
        res.result = True
        return res

    def _ik(self, req, res):
        try:
            q = self.psm.inverse_kinematics(np.asarray(req.jp, float), pose_to_matrix(req.cp))
        except ValueError as exc:
            res.result, res.message = False, ("incorrect number of joints" if "incorrect" in str(exc)
                                             else "inverse kinematics failed")
            res.jp = list(np.asarray(req.jp, float))
            return res
        res.jp, res.result = [float(v) for v in q], True
        return res

    def _trigger_state(self, _req, res):
        st = self.state.operating_state()
        stamp = res.operating_state.header.stamp
        stamp.sec, stamp.nanosec = divmod(self._event_stamp_ns(), 1_000_000_000)
        res.operating_state.state, res.operating_state.is_homed = st.state, st.is_homed
        res.operating_state.is_busy = st.is_busy
        return res

    # -- commands (main thread) -------------------------------------------------------------
    def apply(self, key: str, m) -> bool:
        """Apply one received message; True when a motion command was obeyed. A malformed
        one raises ValueError (the server counts and logs it)."""
        psm, state, t = self.psm, self.state, self.psm.world.t
        if key == "state_command":
            state.command(str(m.string), t)
            return False
        if key in ("use_gravity_compensation", "body/set_cf_orientation_absolute", "emulate_tool_present"):
            value = bool(m.data)
            if key == "use_gravity_compensation":
                psm.use_gravity_compensation(value)
            elif key == "body/set_cf_orientation_absolute":
                psm.body_cf_absolute = value
            else:
                # the simulated PSM always carries its tool: accepted and logged, as a tool
                # that is really present makes the emulation moot
                psm.messages.append(("status", f"{self.name}: emulate_tool_present {value} (the simulated "
                                               f"{psm.tool.name} is always present)"))
            return False
        if key == "trajectory_j/set_ratio":
            psm.set_trajectory_ratio(float(m.data))
            return False
        act = self._motion(key, m)
        # the dVRK's names in its "arm not ready" warning: jaw_servo_jp, body_servo_cf, ...
        return state.motion(key.replace("/", "_"), t, act, moving=key in MOVES, servo=key not in ("hold",))

    def _motion(self, key: str, m):
        psm = self.psm
        if key in ("servo_jp", "move_jp", "servo_jr", "move_jr"):
            p = list(m.position)
            v = list(m.velocity)
            fn = {"servo_jp": lambda: psm.servo_jp(p, v if len(v) else None), "move_jp": lambda: psm.move_jp(p),
                  "servo_jr": lambda: psm.servo_jr(p), "move_jr": lambda: psm.move_jr(p)}[key]
            if len(p) < 6:
                raise ValueError(f"{key} needs 6 joint positions, got {len(p)}")
            return fn
        if key == "servo_jf":
            e = list(m.effort)
            if len(e) < 6:
                raise ValueError(f"servo_jf needs 6 joint efforts, got {len(e)}")
            return lambda: psm.servo_jf(e)
        if key in ("servo_cp", "move_cp"):
            T = pose_to_matrix(m.pose)
            return (lambda: psm.servo_cp(T)) if key == "servo_cp" else (lambda: psm.move_cp(T))
        if key in ("body/servo_cf", "spatial/servo_cf"):
            f, tq = m.wrench.force, m.wrench.torque
            w = [f.x, f.y, f.z, tq.x, tq.y, tq.z]
            return lambda: psm.servo_cf(w, kind=key.split("/")[0])
        if key == "servo_ci":
            goal = impedance_from_msg(m)
            return lambda: psm.servo_ci(goal)
        if key == "hold":
            return psm.hold
        if key == "free":
            return psm.free
        if key in ("jaw/servo_jp", "jaw/move_jp"):
            p = list(m.position)
            if len(p) < 1:
                raise ValueError(f"{key} needs 1 jaw position, got 0")
            return (lambda: psm.jaw_servo_jp(p)) if key == "jaw/servo_jp" else (lambda: psm.jaw_move_jp(p))
        if key == "jaw/servo_jf":
            e = list(m.effort)
            if len(e) < 1:
                raise ValueError("jaw/servo_jf needs 1 jaw effort, got 0")
            return lambda: psm.jaw_servo_jf(e)
        raise ValueError(f"unknown command {key}")

    # -- publishing (main thread) ------------------------------------------------------------
    def refresh_watched(self) -> None:
        """The streams to publish: those with a subscriber."""
        self.watched = frozenset(k for k, p in self.pub.items() if p.get_subscription_count() > 0)

    def _matched(self, key: str, subscribers: int) -> None:
        """A subscriber came or went (executor thread): the set is replaced, never changed in place."""
        self.watched = self.watched | {key} if subscribers > 0 else self.watched - {key}

    def publish_events(self) -> None:
        """The operating state's and the arm's events and messages, in order."""
        T, state, psm = self._T, self.state, self.psm
        for st in state.events:
            m = T["state"]()
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(self._event_stamp_ns(), 1_000_000_000)
            m.header.frame_id = self.name
            m.state, m.is_homed, m.is_busy = st.state, st.is_homed, st.is_busy
            self.event_pub["operating_state"].publish(m)
        state.events.clear()
        for kind, value in psm.events:
            if kind == "goal_reached":
                self.event_pub["goal_reached"].publish(T["bool"](data=bool(value)))
            elif kind == "ratio":
                for k in ("trajectory_j/ratio", "trajectory_j/ratio_v", "trajectory_j/ratio_a"):
                    self.event_pub[k].publish(T["float"](data=float(value)))
        psm.events.clear()
        log = self.node.get_logger()
        for level, text in state.messages + psm.messages:
            # (one call site per severity: rclpy ties a call site to its first severity)
            if level == "error":
                log.error(text)
            elif level == "warning":
                log.warning(text)
            else:
                log.info(text)
            self.event_pub[level].publish(T["string"](data=text))
        state.messages.clear()
        psm.messages.clear()

    def _in_base(self, q_local: list[float]) -> list[float]:
        """A local orientation in the base frame: the base's quaternion (kept while the base stays) times it."""
        base = self.psm.base_frame
        if self._base is None or not np.array_equal(self._base[0], base):
            self._base = (base.copy(), _quat(base))
        return _turned(self._base[1], q_local)

    def _send(self, key: str, data: bytes) -> None:
        self.pub[key].publish(data)
        self.sent[key] += 1

    def publish_streams(self, t: float) -> None:
        """Every watched stream at sim time t, built only when watched."""
        self.published += 1
        w = self.watched
        if not w:
            return
        psm, send, stamp = self.psm, self._send, self._stamp_ns(t)
        names = self._names
        if "measured_js" in w or "jaw/measured_js" in w:
            q, dq, e = (v.tolist() for v in psm.measured_js())
            if "measured_js" in w:
                send("measured_js", cdr.write_joint_state(stamp, "", names, q[:6], dq[:6], e[:6]))
            if "jaw/measured_js" in w:
                send("jaw/measured_js", cdr.write_joint_state(stamp, "", ("jaw",), q[6:], dq[6:], e[6:]))
        setpoint = None
        if w & _SETPOINTS:
            setpoint = psm.setpoint_js()
            sq, sdq, se = (v.tolist() for v in setpoint)
            if "setpoint_js" in w:
                send("setpoint_js", cdr.write_joint_state(stamp, "", names, sq[:6], sdq[:6], se[:6]))
            if "jaw/setpoint_js" in w:
                send("jaw/setpoint_js", cdr.write_joint_state(stamp, "", ("jaw",), sq[6:], sdq[6:], se[6:]))
        base = psm.reference_frame
        # a pose in the base frame turns its local quaternion by the base's (one conversion a pose pair)
        if "measured_cp" in w or "local/measured_cp" in w:
            T_local = psm.measured_cp(local=True)
            q_local = _quat(T_local)
            if "local/measured_cp" in w:
                send("local/measured_cp", cdr.write_pose_stamped(stamp, base, T_local[:3, 3].tolist() + q_local))
            if "measured_cp" in w:
                send("measured_cp", cdr.write_pose_stamped(stamp, base, psm.measured_cp()[:3, 3].tolist()
                                                           + self._in_base(q_local)))
        if "setpoint_cp" in w or "local/setpoint_cp" in w:
            T_local = psm.setpoint_cp(local=True, q=setpoint[0])
            q_local = _quat(T_local)
            if "local/setpoint_cp" in w:
                send("local/setpoint_cp", cdr.write_pose_stamped(stamp, base, T_local[:3, 3].tolist() + q_local))
            if "setpoint_cp" in w:
                p = psm.base_frame[:3, :3] @ T_local[:3, 3] + psm.base_frame[:3, 3]
                send("setpoint_cp", cdr.write_pose_stamped(stamp, base, p.tolist() + self._in_base(q_local)))
        for key, local in (("measured_cv", False), ("local/measured_cv", True)):
            if key in w:
                send(key, cdr.write_twist_stamped(stamp, base, psm.measured_cv(local=local).tolist()))
        if "body/measured_cf" in w:
            send("body/measured_cf", cdr.write_wrench_stamped(stamp, psm.name, psm.body_measured_cf().tolist()))
        if "spatial/measured_cf" in w:
            send("spatial/measured_cf", cdr.write_wrench_stamped(stamp, base, psm.spatial_measured_cf().tolist()))
        for key in ("body/jacobian", "spatial/jacobian"):
            if key in w:
                J = psm.jacobian(key.split("/")[0])
                send(key, cdr.write_float64_multi_array(JACOBIAN_DIMS, J.ravel().tolist()))

    def publish_initial(self) -> None:
        """What a client that connects first finds: the trajectory ratio (latched nowhere on
        the dVRK either; sent once at start)."""
        self.psm.events.append(("ratio", self.psm.ratio))

    def close(self) -> None:
        for s in self.services:
            self.node.destroy_service(s)
