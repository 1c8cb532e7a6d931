"""A whole dVRK PSM on the simulated rig: six joints and the jaw behind the dVRK arm's control modes.

`FakePSM` is what `rig sim` serves for each arm over the CRTK topics (rig.sim_server.crtk_bridge). It
follows sawIntuitiveResearchKit's arm and PSM components (mtsIntuitiveResearchKitArm.cpp,
mtsIntuitiveResearchKitPSM.cpp) where a client can see the difference:

* Joints 1-3 are the simulated world's plant (identified dynamics, friction, the joint
  PID of `rig.sim.world`); joints 4-6 and the jaw are a `rig.model.wrist_plant.WristPlant` (inertia,
  friction, the dVRK's PID gains, the tool's stops). Positions are in the dVRK's joint
  order: outer_yaw, outer_pitch, outer_insertion, outer_roll, outer_wrist_pitch,
  outer_wrist_yaw, then the jaw on its own topics.
* Kinematics are the dVRK's PSM with its tool (`rig.model.psm_arm_kinematics`, tool definitions
  in `rig.model.psm_tool`, the large needle driver by default). `local` poses are in the arm's
  kinematic base (the RCM at the origin); `measured_cp` is `base_frame @ local`, and the
  base frame is the identity named "<arm>_base" unless one is set, as on a dVRK without a
  set-up joint or registration.
* Control space and mode as the dVRK's `SetControlSpaceAndMode`: servo_jp / servo_jr /
  hold (joint position: the PID holds the last goal), move_jp / move_jr / move_cp (joint
  trajectory: a synchronised profile within the trajectory's velocity and acceleration,
  scaled by `trajectory_j/set_ratio`; move_cp solves the inverse kinematics once), servo_cp
  (cartesian position: inverse kinematics every period, seeded with the set-point),
  servo_jf / free (joint effort), body or spatial servo_cf (cartesian effort: J^T w with the
  body or spatial Jacobian; `body/set_cf_orientation_absolute` rotates a body wrench given
  in the base frame), servo_ci (the dVRK's `osaCartesianImpedanceController`: a per-axis
  spring, damper, bias and deadband about a pose, its wrench applied through the body
  Jacobian). Goals are clipped to the joint limits once the arm is homed (`clip_jp`).
  Cartesian commands need the tool past the cannula (the shaft end 45 mm - 2 mm from the
  RCM), else the dVRK's warning and no switch.
* The jaw: jaw/servo_jp and jaw/move_jp keep the arm's space and move only the jaw (the
  others hold their goal); jaw/servo_jf adds a jaw effort to a cartesian effort mode.
* `use_gravity_compensation(True)` adds the nominal PSM model's gravity torque of joints
  1-3 (what a dVRK would have configured, not the simulated plant's true parameters) to
  every effort command, as the dVRK's feed-forward does.
* Busy: a move's trajectory ends at its goal (the set-point, as Reflexxes' final state),
  which ends the busy state on the next period; `goal_reached` events say whether it did.

What the server publishes and the operating state (enable, home, faults, "arm not ready")
live elsewhere: the state in `drivers.arm.fake_arm_state.FakeArmState` (which wraps this object),
the topics in `rig.sim_server.crtk_bridge`. Messages for <arm>/status, warning and error are queued in
`messages` as (level, text), other events (goal_reached, trajectory ratio) in `events`.

Units: rad and m (joint 3), N m and N, s.
"""

from __future__ import annotations

import numpy as np

from drivers.arm.crtk import PSM_JOINT_NAMES
from drivers.arm.sim import DDQ_MAX, JointTrajectory
from rig.model import psm_kinematics as K
from rig.model.psm_arm_kinematics import rotation_error
from rig.model.psm_tool import SAFE_DISTANCE_FROM_RCM, SAFE_DISTANCE_FROM_RCM_BUFFER

#: rad/s and rad/s^2 of joints 4-6 and the jaw at trajectory ratio 1 (our choice: the
#: tool's wrist turns a quarter turn in about half a second)
WRIST_DQ = np.array([3.0, 3.0, 3.0, 3.0])
WRIST_DDQ = np.array([20.0, 20.0, 20.0, 20.0])

JOINT, CARTESIAN = "joint", "cartesian"
POSITION, TRAJECTORY, EFFORT = "position", "trajectory", "effort"
BODY = "body"


def _vector(values, n: int, what: str, at_least: int | None = None) -> np.ndarray:
    v = np.asarray(values, dtype=float).ravel()
    need = n if at_least is None else at_least
    if v.size < need:
        raise ValueError(f"{what} needs {need} values, got {v.size}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} contains a non-finite value: {v.tolist()}")
    return v


class Impedance:
    """A crtk_msgs/CartesianImpedance goal as the dVRK's osaCartesianImpedanceController runs it.

    force_position (m) and the orientations (3x3) of the force and torque frames; per
    half-plane (positive, negative error along each axis of those frames) the gains p
    (N/m, N m/rad), d (N s/m, N m s/rad), bias (N, N m) and deadband (m, rad). The wrench
    is p * err + d * vel + bias per axis (err = pose - goal: a restoring spring has p < 0,
    as in the dVRK's examples), in the base frame.
    """

    def __init__(self, force_position, force_orientation, torque_orientation, gains):
        self.force_position = np.asarray(force_position, float)
        self.force_orientation = np.asarray(force_orientation, float)
        self.torque_orientation = np.asarray(torque_orientation, float)
        # gains: {"position_positive": (p, d, bias, deadband), ...} each a (3,) array
        self.gains = {k: tuple(np.asarray(x, float) for x in v) for k, v in gains.items()}

    @staticmethod
    def _axes(err, vel, pos, neg):
        out = np.zeros(3)
        for i in range(3):
            p, d, bias, dead = pos if err[i] > 0 else neg
            if err[i] > 0:
                e = max(err[i] - abs(dead[i]), 0.0)
            else:
                e = min(err[i] + abs(dead[i]), 0.0)
            out[i] = e * p[i] + vel[i] * d[i] + bias[i]
        return out

    def wrench(self, T: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(force, torque) in the base frame for the pose T (4x4) and twist (v, w) in the base frame."""
        Rf, Rt, g = self.force_orientation, self.torque_orientation, self.gains
        err = Rf.T @ (T[:3, 3] - self.force_position)
        force = Rf @ self._axes(err, Rf.T @ v, g["position_positive"], g["position_negative"])
        err_r = rotation_error(Rt.T @ T[:3, :3], np.eye(3))  # axis times angle (vctAxAnRot3)
        torque = Rt @ self._axes(err_r, Rt.T @ w, g["orientation_positive"], g["orientation_negative"])
        return np.concatenate([force, torque])


def _wrench(J: np.ndarray, effort: np.ndarray) -> np.ndarray:
    """pinv(J^T) effort, as the dVRK computes a measured wrench: a solve while J is regular
    (the same numbers in a fifth of pinv's time, twice a period), pinv where it is singular."""
    try:
        w = np.linalg.solve(J.T, effort)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(J.T) @ effort
    if not np.all(np.abs(w) < 1e9):  # (near) singular: pinv drops what solve blows up
        return np.linalg.pinv(J.T) @ effort
    return w


class FakePSM:
    """One arm of a `rig.sim.world.SimWorld` as a whole dVRK PSM (see the module docstring).

    world, name, clock: the simulated rig, the arm's name, its clock (`rig.devices.clock.SimClock`);
    tool: a `rig.model.psm_tool.Tool` (default: the large needle driver); velocity_ratio: fraction
    of Table 4.2's velocities a trajectory plans for at ratio 1 (as `drivers.arm.sim.SimArm`).
    """

    joint_names = PSM_JOINT_NAMES

    def __init__(self, world, name: str, clock, tool=None, velocity_ratio: float = 0.5):
        from rig.model.psm_arm_kinematics import PSMKinematics
        from rig.model.psm_dynamics import PSMDynamics
        from rig.model.psm_tool import DEFAULT_TOOL
        from rig.model.wrist_plant import WristPlant

        if name not in world.arms:
            raise ValueError(f"no arm {name!r} in the simulated world; it has {world.names}")
        self.world = world
        self.name = name
        self.clock = clock
        self.tool = tool if tool is not None else DEFAULT_TOOL
        self.kin = PSMKinematics(self.tool)
        a = world.arms[name]
        self._sl = a.sl
        self.wrist = WristPlant(self.tool, rng=np.random.default_rng(world.seed * 7919 + a.index + 17))
        self.q_min = np.concatenate([self.kin.q_min, [self.tool.jaw_min]])
        self.q_max = np.concatenate([self.kin.q_max, [self.tool.jaw_max]])
        self.dq_base = np.concatenate([velocity_ratio * K.DQ_MAX, WRIST_DQ])
        self.ddq_base = np.concatenate([DDQ_MAX, WRIST_DDQ])
        self.ratio = 1.0
        self.home_position = np.concatenate([np.asarray(a.spec.q0, float), np.zeros(4)])
        self.base_frame = np.eye(4)
        self.reference_frame = f"{name}_base"
        # gravity in the arm's base frame, for the configured (nominal) model's compensation
        g_arm = a.spec.base[:3, :3].T @ np.asarray(world.model.gravity.linear, float)
        self._gc_model = PSMDynamics(gravity=g_arm)
        self.gravity_compensation = False
        self.body_cf_absolute = False
        self.space: str | None = None
        self.mode: str | None = None
        self.trajectory: JointTrajectory | None = None
        self._servo_goal = self.home_position.copy()
        self._servo_v = np.zeros(7)
        self._new_goal = False
        self._servo_cs: np.ndarray | None = None
        self._servo_jf = np.zeros(6)
        self._jaw_jf = 0.0
        self._servo_cf = np.zeros(6)
        self._cf_type = BODY
        self._impedance: Impedance | None = None
        self._cartesian_safe_warned = False
        self.messages: list[tuple[str, str]] = []
        self.events: list[tuple[str, object]] = []
        self.powered = world.mode(name) != "off"
        self.homed = False  # set by the operating state: joint goals are clipped once homed
        self._cache_key = None
        self._cache: dict = {}
        self._sample_key = None
        self._sample = None

    # -- reading (what the dVRK computes in get_robot_data) --------------------------------
    def measured_js(self):
        """(position (7,), velocity (7,), effort (7,)): joints 1-6 then the jaw. One sample
        per period (the encoders and currents read once): every reading of a period, the
        poses and wrenches included, comes from it."""
        key = self.world.steps
        if self._sample_key != key:
            q3, dq3, e3 = self.world.measured_js(self.name)
            qw, dqw, ew = self.wrist.measured()
            self._sample = (np.concatenate([q3, qw]), np.concatenate([dq3, dqw]), np.concatenate([e3, ew]))
            self._sample_key = key
        q, dq, e = self._sample
        return q.copy(), dq.copy(), e.copy()

    def setpoint_js(self):
        """(position, velocity, effort) set-points of joints 1-6 and the jaw; in effort mode
        the position set-point follows the measured position (the PID is in torque mode)."""
        q3, dq3, e3 = self.world.setpoint_js(self.name)
        if self.world.mode(self.name) != "position":
            q3, dq3 = (v[:3] for v in self.measured_js()[:2])
        qw, dqw, ew = self.wrist.setpoint()
        return np.concatenate([q3, qw]), np.concatenate([dq3, dqw]), np.concatenate([e3, ew])

    def _kinematics(self):
        """The measured pose, twist, Jacobians and wrenches of this period (computed once)."""
        key = self.world.steps
        if self._cache_key == key:
            return self._cache
        q, dq, effort = self.measured_js()
        T_local, Jb, Js = self.kin.forward_and_jacobians(q[:6])
        T = self.base_frame @ T_local
        R = T[:3, :3]
        body_twist = Jb @ dq[:6]
        wrench_body = _wrench(Jb, effort[:6])
        wrench_abs = np.concatenate([R @ wrench_body[:3], R @ wrench_body[3:]])
        self._cache = {"q": q, "dq": dq, "effort": effort, "T_local": T_local, "T": T, "Jb": Jb, "Js": Js,
                       "v_local": body_twist, "v": np.concatenate([R @ body_twist[:3], R @ body_twist[3:]]),
                       "wrench_body": wrench_body, "wrench_abs": wrench_abs,
                       "wrench_spatial": _wrench(Js, effort[:6])}
        self._cache_key = key
        return self._cache

    def measured_cp(self, local: bool = False) -> np.ndarray:
        k = self._kinematics()
        return (k["T_local"] if local else k["T"]).copy()

    def setpoint_cp(self, local: bool = False, q=None) -> np.ndarray:
        """The pose of the set-point joints (`q`, the first six of setpoint_js, when already read)."""
        T = self.kin.forward((self.setpoint_js()[0] if q is None else q)[:6])
        return T if local else self.base_frame @ T

    def measured_cv(self, local: bool = False) -> np.ndarray:
        """Twist (v, w) of the tool tip: body frame if local, else in the base frame."""
        return self._kinematics()["v_local" if local else "v"].copy()

    def body_measured_cf(self) -> np.ndarray:
        """Wrench (f, m) from the measured efforts through the body Jacobian; in the base
        frame's orientation when body/set_cf_orientation_absolute is on."""
        k = self._kinematics()
        return (k["wrench_abs"] if self.body_cf_absolute else k["wrench_body"]).copy()

    def spatial_measured_cf(self) -> np.ndarray:
        return self._kinematics()["wrench_spatial"].copy()

    def jacobian(self, kind: str) -> np.ndarray:
        return self._kinematics()["Jb" if kind == BODY else "Js"].copy()

    def forward_kinematics(self, jp, local: bool = False) -> np.ndarray:
        """The dVRK's forward_kinematics service: the frame of the first len(jp) joints
        (all six: the tool tip), times the base frame unless local."""
        jp = _vector(jp, 1, "forward_kinematics jp", at_least=1)
        if jp.size > 6:
            raise ValueError("too many joints")
        if jp.size == 6:
            T = self.kin.forward(jp)
        else:
            T = self.kin.frames(np.concatenate([jp, np.zeros(6 - jp.size)]))[jp.size - 1]
        return T if local else self.base_frame @ T

    def inverse_kinematics(self, jp, cp: np.ndarray) -> np.ndarray:
        """The dVRK's inverse_kinematics service: joints for the pose `cp` given as is (the
        dVRK applies no base frame here), seeded with `jp` (six values). Raises ValueError."""
        jp = np.asarray(jp, dtype=float).ravel()
        if jp.size != 6:
            raise ValueError("incorrect number of joints")
        return self._ik(jp, np.asarray(cp, float))

    def _ik(self, seed: np.ndarray, T_local: np.ndarray) -> np.ndarray:
        """The dVRK's PSM::InverseKinematics: refused within 1 mm of the RCM, roll to the turn
        closest to the seed's, the shaft end kept SAFE_DISTANCE_FROM_RCM out (raises IKError)."""
        from rig.model.psm_arm_kinematics import IK_MIN_DISTANCE_TO_RCM

        if np.linalg.norm(T_local[:3, 3]) < IK_MIN_DISTANCE_TO_RCM:
            self.messages.append(("warning", f"{self.name}: InverseKinematics, can't solve IK too close to RCM"))
        return self.kin.inverse(T_local, np.asarray(seed, float), keep_safe_distance=True)

    # -- control space and mode ---------------------------------------------------------
    def _safe_for_cartesian(self) -> bool:
        q = self.measured_js()[0]
        depth = float(np.linalg.norm(self.kin.shaft_point(q[:6])))
        return depth >= SAFE_DISTANCE_FROM_RCM - SAFE_DISTANCE_FROM_RCM_BUFFER

    def _set_space_mode(self, space: str, mode: str) -> bool:
        """The dVRK's SetControlSpaceAndMode: False (and a warning, once) when cartesian
        space is asked for before the tool is past the cannula."""
        if space == self.space and mode == self.mode:
            return True
        space_changed = space != self.space
        if space_changed:
            if space == CARTESIAN and not self._safe_for_cartesian():
                if not self._cartesian_safe_warned:
                    self.messages.append(("warning", f"{self.name}: tool/endoscope needs to be inserted past the "
                                                     "cannula to switch to cartesian space"))
                    self._cartesian_safe_warned = True
                return False
            self._cartesian_safe_warned = False
            self.space = space
        if mode != self.mode:
            sp = self.setpoint_js()[0]
            if self.mode == TRAJECTORY and self.trajectory is not None:
                self._stop_trajectory(False)
            if mode in (POSITION, TRAJECTORY):
                self._servo_goal = sp.copy()
                self._servo_v = np.zeros(7)
                self._new_goal = False
                if self.mode == EFFORT:
                    self._jaw_jf = 0.0
            elif mode == EFFORT:
                self._servo_jf = np.zeros(6)
            self.mode = mode
        self.messages.append(("status", f"{self.name}: control {self.space}/{mode}"))
        return True

    def _clip(self, q: np.ndarray) -> np.ndarray:
        if not self.homed:
            return q
        n = q.size
        return np.clip(q, self.q_min[:n], self.q_max[:n])

    # -- commands (each after the operating state accepted it) ---------------------------
    def servo_jp(self, position, velocity=None) -> None:
        """Joint position goal of joints 1-6 (and the jaw if 7 values), velocity optional."""
        p = _vector(position, 6, "servo_jp", at_least=6)
        self._set_space_mode(JOINT, POSITION)
        goal = self._servo_goal.copy()
        goal[:min(p.size, 7)] = p[:7]
        self._servo_goal = goal
        v = np.zeros(7)
        if velocity is not None and len(velocity):
            vv = _vector(velocity, 6, "servo_jp velocity", at_least=min(len(velocity), 6))
            v[:min(vv.size, 6)] = vv[:6]
        self._servo_v = v
        self._new_goal = True
        self.powered = True

    def servo_jr(self, difference) -> None:
        d = _vector(difference, 6, "servo_jr", at_least=6)
        self._set_space_mode(JOINT, POSITION)
        if not self._new_goal:
            self._servo_goal = self.setpoint_js()[0]
        self._servo_goal[:6] += d[:6]
        self._servo_v = np.zeros(7)
        self._new_goal = True

    def move_jp(self, position, wait: bool = False, timeout: float = 10.0) -> bool:
        """Joint trajectory to joints 1-6 (and jaw if 7 values); busy until its end."""
        p = _vector(position, 6, "move_jp", at_least=6)
        self._set_space_mode(JOINT, TRAJECTORY)
        goal = self._traj_goal()
        goal[:min(p.size, 7)] = p[:7]
        self._start_trajectory(goal)
        return True

    def move_jr(self, difference) -> None:
        d = _vector(difference, 6, "move_jr", at_least=6)
        self._set_space_mode(JOINT, TRAJECTORY)
        goal = (self.trajectory.goal.copy() if self.trajectory is not None else self.setpoint_js()[0])
        goal[:6] += d[:6]
        self._start_trajectory(goal)

    def move_cp(self, T: np.ndarray) -> bool:
        """Cartesian goal (4x4 in the base frame): inverse kinematics once, then a joint
        trajectory. False (an error, busy ends) when the kinematics have no solution."""
        from rig.model.psm_arm_kinematics import IKError

        if not self._set_space_mode(CARTESIAN, TRAJECTORY):
            return False
        q = self.measured_js()[0]
        try:
            sol = self._ik(q[:6].copy(), np.linalg.inv(self.base_frame) @ T)
        except (IKError, ValueError) as exc:
            self.messages.append(("error", f"{self.name}: unable to solve inverse kinematics ({exc})"))
            self.events.append(("goal_reached", False))
            return False
        goal = self._traj_goal()
        goal[:6] = sol
        self._start_trajectory(goal)
        return True

    def servo_cp(self, T: np.ndarray) -> None:
        if not self._set_space_mode(CARTESIAN, POSITION):
            return
        self._servo_cs = np.asarray(T, float).copy()
        self._new_goal = True

    def servo_jf(self, effort) -> None:
        e = _vector(effort, 6, "servo_jf", at_least=6)
        self._set_space_mode(JOINT, EFFORT)
        self._servo_jf = e[:6].copy()
        self.powered = True

    def free(self) -> None:
        self.servo_jf(np.zeros(6))

    def servo_cf(self, wrench, kind: str = BODY) -> None:
        w = _vector(wrench, 6, f"{kind}/servo_cf")
        if not self._set_space_mode(CARTESIAN, EFFORT):
            return
        self._impedance = None
        self._servo_cf = w[:6].copy()
        if self._cf_type != kind:
            self._cf_type = kind
            self.messages.append(("status", f"{self.name}: effort cartesian WRENCH_{kind.upper()}"))

    def servo_ci(self, goal: Impedance) -> None:
        if not self._set_space_mode(CARTESIAN, EFFORT):
            return
        self._impedance = goal
        self.body_cf_absolute = True
        if self._cf_type != BODY:
            self._cf_type = BODY
            self.messages.append(("status", f"{self.name}: effort cartesian WRENCH_BODY"))

    def hold(self) -> None:
        """Hold the present set-point under the PID (joint position mode)."""
        self._set_space_mode(JOINT, POSITION)
        self._servo_goal = self.setpoint_js()[0]
        if self.world.mode(self.name) != "position":
            self._servo_goal[:3] = self.measured_js()[0][:3]
        self._servo_v = np.zeros(7)
        self._new_goal = True
        self.powered = True
        self._apply_position(self._servo_goal, self._servo_v)

    def jaw_servo_jp(self, position) -> None:
        p = _vector(position, 1, "jaw/servo_jp")
        if self.mode != POSITION:
            if self.space == CARTESIAN:
                self._set_space_mode(CARTESIAN, POSITION)
                if self._servo_cs is None:
                    self._servo_cs = self.setpoint_cp()
            else:
                self._set_space_mode(JOINT, POSITION)
                self._servo_goal = self.setpoint_js()[0]
        self._servo_goal[6] = p[0]
        self._new_goal = True

    def jaw_move_jp(self, position) -> None:
        p = _vector(position, 1, "jaw/move_jp")
        if self.mode != TRAJECTORY:
            self._set_space_mode(CARTESIAN if self.space == CARTESIAN else JOINT, TRAJECTORY)
        goal = self._traj_goal()
        goal[6] = p[0]
        self._start_trajectory(goal)

    def jaw_servo_jf(self, effort) -> None:
        e = _vector(effort, 1, "jaw/servo_jf")
        if not (self.space == CARTESIAN and self.mode == EFFORT):
            if not self._set_space_mode(CARTESIAN, EFFORT):
                return
            self._servo_cf = np.zeros(6)
        self._jaw_jf = float(e[0])

    def set_trajectory_ratio(self, ratio: float) -> None:
        if not (0.0 < ratio <= 1.0) or not np.isfinite(ratio):
            self.messages.append(("warning", f"{self.name}: trajectory_j_set_ratio, ratio must be within ]0;1], "
                                             f"received {ratio:g}"))
            return
        self.ratio = float(ratio)
        self.events.append(("ratio", self.ratio))

    def use_gravity_compensation(self, on: bool) -> None:
        self.gravity_compensation = bool(on)
        self.messages.append(("status", f"{self.name}: gravity compensation {'on' if on else 'off'}"))

    def power_off(self) -> None:
        self.trajectory = None
        self.space = self.mode = None
        self.powered = False
        self.world.power_off(self.name)
        self.wrist.off()

    # -- trajectories ---------------------------------------------------------------------
    def _traj_goal(self) -> np.ndarray:
        return self.trajectory.goal.copy() if self.trajectory is not None else self.setpoint_js()[0]

    def _start_trajectory(self, goal: np.ndarray) -> None:
        goal = goal.copy()
        goal[:6] = self._clip(goal[:6])
        goal[6] = float(np.clip(goal[6], self.q_min[6], self.q_max[6]))
        start = self.setpoint_js()[0]
        if self.world.mode(self.name) != "position":
            start[:3] = self.measured_js()[0][:3]
        self.trajectory = JointTrajectory.plan(start, goal, self.clock.now(), self.ratio * self.dq_base,
                                               self.ratio * self.ddq_base)
        self.powered = True

    def _stop_trajectory(self, reached: bool) -> None:
        self.trajectory = None
        self.events.append(("goal_reached", reached))

    def is_moving(self) -> bool:
        """True while a trajectory (move_jp, move_jr, move_cp, jaw/move_jp, homing) runs."""
        return self.trajectory is not None

    def arrived(self) -> bool:
        """No trajectory under way and joints 1-3 within the arrival tolerance of the goal, at rest."""
        from drivers.arm.crtk import ARRIVAL_TOLERANCE, REST_VELOCITY

        if self.trajectory is not None:
            return False
        q, dq = (v[:3] for v in self.measured_js()[:2])
        goal = self._servo_goal[:3]
        return bool(np.all(np.abs(q - goal) <= ARRIVAL_TOLERANCE) and np.all(np.abs(dq) <= REST_VELOCITY))

    # -- the servo loop (once per period, before the world steps) --------------------------
    def _apply_position(self, q: np.ndarray, v: np.ndarray) -> None:
        q = q.copy()
        q[:6] = self._clip(q[:6])
        q[6] = float(np.clip(q[6], self.q_min[6], self.q_max[6]))
        self.world.servo_jp(self.name, q[:3], v[:3])
        self.wrist.servo_jp(q[3:7], v[3:7])

    def _apply_effort(self, tau6: np.ndarray) -> None:
        tau = tau6.copy()
        if self.gravity_compensation:
            tau[:3] += self._gc_model.gravity_torque(self.measured_js()[0][:3])
        self.world.servo_jf(self.name, tau[:3])
        self.wrist.servo_jf(np.concatenate([tau[3:6], [self._jaw_jf]]))

    def control(self, t: float) -> None:
        """Set the PIDs' goals or efforts for the period starting at t (the dVRK's control callback)."""
        if not self.powered or self.mode is None:
            return
        dt = self.world.dt
        if self.mode == TRAJECTORY:
            traj = self.trajectory
            if traj is None:
                return
            q, v = traj.sample(t + dt)
            self._servo_goal = q.copy()
            self._apply_position(q, v)
            if t + dt >= traj.end():
                self._stop_trajectory(True)
        elif self.mode == POSITION:
            if self.space == CARTESIAN and self._servo_cs is not None and self._new_goal:
                from rig.model.psm_arm_kinematics import IKError

                seed = self.setpoint_js()[0][:6]
                try:
                    sol = self._ik(seed, np.linalg.inv(self.base_frame) @ self._servo_cs)
                except (IKError, ValueError) as exc:
                    self.messages.append(("error", f"{self.name}: unable to solve inverse kinematics ({exc})"))
                    self._new_goal = False
                    return
                self._servo_goal[:6] = sol
                self._apply_position(self._servo_goal, np.zeros(7))
                self._new_goal = False
            elif self._new_goal:
                self._apply_position(self._servo_goal, self._servo_v)
                self._new_goal = False
        elif self.mode == EFFORT:
            if self.space == CARTESIAN:
                k = self._kinematics()
                if self._cf_type == BODY:
                    if self._impedance is not None:
                        w = self._impedance.wrench(k["T"], k["v"][:3], k["v"][3:])
                        R = k["T"][:3, :3]
                        w = np.concatenate([R.T @ w[:3], R.T @ w[3:]])
                    elif self.body_cf_absolute:
                        R = k["T"][:3, :3]
                        w = np.concatenate([R.T @ self._servo_cf[:3], R.T @ self._servo_cf[3:]])
                    else:
                        w = self._servo_cf
                    tau = k["Jb"].T @ w
                else:
                    tau = k["Js"].T @ self._servo_cf
                self._apply_effort(tau)
            else:
                self._apply_effort(self._servo_jf)

    def step_wrist(self) -> None:
        """Advance the wrist and jaw plant one period (the world steps joints 1-3)."""
        self.wrist.step(self.world.dt)
