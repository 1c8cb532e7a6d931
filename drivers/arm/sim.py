"""The in-process dVRK arm fake: the Arm protocol on one arm of the simulated world.

`SimArm` is the fast fake beside `drivers.arm.dvrk_arm.RosArm`: same vocabulary, no ROS.
`rig sim` serves the very same object over the dVRK topics, so the trajectory generator
and console behaviour seen through ROS are these.

* servo_jp / servo_jf go straight to the world's joint PID / effort input, as the dVRK's
  servo commands go to its 1.5 kHz (here: rig rate) controller;
* move_jp runs a trajectory generator in the "device": a minimum-jerk (quintic) profile,
  all joints synchronised, whose duration keeps the peak velocity within `velocity_ratio`
  of Table 4.2 and the peak acceleration within `acceleration_ratio` of `DDQ_MAX`. It is
  advanced by a clock listener, so with wait=False the arm keeps moving while the caller
  ticks the clock for other reasons, and with wait=True move_jp ticks the clock itself;
* measured_cp is the forward kinematics of the *measured* joints as the dVRK reports it: the
  tool tip of its whole PSM with the large needle driver, wrist straight
  (`rig.model.psm_arm_kinematics.RIG_TIP_TO_TOOL_TIP` beyond the shaft end this module's
  kinematics calls the tip), in the arm's base frame (the RCM frame, "<arm>_base", as a dVRK
  without a set-up joint); `measured_cp_world()` is the same pose in the world frame.

Units: rad and m for joints (joint 3 in m), N m and N for efforts, s for times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.arm.crtk import ARRIVAL_TOLERANCE, PSM_JOINT_NAMES, REST_VELOCITY, Wrench, body_wrench_from_effort
from drivers.interfaces import JointState, Pose
from rig.model import psm_kinematics as K

# The rig's own choice (Table 4.2 gives no accelerations): about what the dVRK's default
# move_jp reaches on a PSM, rad/s^2, rad/s^2, m/s^2.
DDQ_MAX = np.array([6.0, 6.0, 1.2])
# Minimum-jerk profile s(u) = 10u^3 - 15u^4 + 6u^5 on u in [0, 1]: its peak speed is 15/8
# and its peak acceleration 10/sqrt(3) times the average (per unit time, per unit distance).
_PEAK_SPEED = 15.0 / 8.0
_PEAK_ACCEL = 10.0 / np.sqrt(3.0)


@dataclass(frozen=True)
class JointTrajectory:
    """A synchronised minimum-jerk move from `start` to `goal` beginning at `t0` (s)."""

    start: np.ndarray
    goal: np.ndarray
    t0: float
    duration: float

    @classmethod
    def plan(cls, start: np.ndarray, goal: np.ndarray, t0: float, dq_max: np.ndarray,
             ddq_max: np.ndarray) -> "JointTrajectory":
        """The shortest profile whose peak |dq| <= dq_max and |ddq| <= ddq_max on every joint."""
        d = np.abs(np.asarray(goal, float) - np.asarray(start, float))
        t_v = _PEAK_SPEED * d / dq_max
        t_a = np.sqrt(_PEAK_ACCEL * d / ddq_max)
        return cls(np.array(start, float), np.array(goal, float), float(t0),
                   float(max(np.max(t_v), np.max(t_a), 0.0)))

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at time t; the goal at rest after the end."""
        if self.duration <= 0.0 or t >= self.t0 + self.duration:
            return self.goal.copy(), np.zeros_like(self.goal)
        u = max(0.0, (t - self.t0) / self.duration)
        s = u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
        ds = 30.0 * u * u * (1.0 - u) ** 2 / self.duration
        delta = self.goal - self.start
        return self.start + s * delta, ds * delta

    def end(self) -> float:
        return self.t0 + self.duration


def _joints(values, what: str) -> np.ndarray:
    """The first three joints of a command, checked finite (ROS messages may carry more)."""
    v = np.asarray(values, dtype=float).ravel()
    if v.size < 3:
        raise ValueError(f"{what} needs at least 3 joint values (joints 1-3), got {v.size}")
    v = v[:3]
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} contains a non-finite value: {v.tolist()}")
    return v


class SimArm:
    """One PSM of a `rig.sim.world.SimWorld`, driven through the Arm protocol.

    world: the simulated rig; name: the arm's name in it ("PSM1"); clock: the rig clock
    that steps the world (`rig.devices.clock.SimClock`); limits: Table 4.2 joint limits that move_jp
    goals must respect; velocity_ratio / acceleration_ratio: fraction of DQ_MAX / DDQ_MAX
    that move_jp plans for (the dVRK's trajectory ratios).
    """

    def __init__(self, world, name: str, clock, limits: K.JointLimits | None = None,
                 velocity_ratio: float = 0.5, acceleration_ratio: float = 1.0):
        if name not in world.arms:
            raise ValueError(f"no arm {name!r} in the simulated world; it has {world.names}")
        if not 0 < velocity_ratio <= 1 or not 0 < acceleration_ratio <= 1:
            raise ValueError("velocity_ratio and acceleration_ratio must be in (0, 1]")
        self.world = world
        self.name = name
        self.clock = clock
        self.limits = limits or K.JointLimits()
        self.velocity_ratio = velocity_ratio
        self.acceleration_ratio = acceleration_ratio
        self.joint_names = PSM_JOINT_NAMES[:3]
        self.home_position = np.asarray(world.arms[name].spec.q0, float).copy()
        self._trajectory: JointTrajectory | None = None
        self._goal: np.ndarray | None = None
        self.powered = world.mode(name) != "off"
        clock.add_listener(self._on_tick)

    # -- reading ----------------------------------------------------------------------
    def measured_js(self) -> JointState:
        """Encoder positions, velocities and measured efforts (noisy, quantised)."""
        q, dq, effort = self.world.measured_js(self.name)
        return JointState(self.clock.now(), q, dq, effort, self.joint_names)

    def drain_js(self) -> list[JointState]:
        """The sample of this tick: in-process, a loop sees every tick."""
        return [self.measured_js()]

    def setpoint_js(self) -> JointState:
        """The PID's position/velocity set-point and the effort applied now."""
        q, dq, effort = self.world.setpoint_js(self.name)
        return JointState(self.clock.now(), q, dq, effort, self.joint_names)

    def measured_cp(self) -> Pose:
        """The dVRK's tool-tip pose from the measured joints (measured_cp: the module docstring)."""
        T = self._tool_tip()
        return Pose(self.clock.now(), T[:3, 3].copy(), T[:3, :3].copy(), f"{self.name}_base")

    def _tool_tip(self) -> np.ndarray:
        """The tool tip (4x4) in the RCM frame, wrist straight, from the measured joints."""
        from rig.model.psm_arm_kinematics import RIG_TIP_TO_TOOL_TIP

        return K.tip_pose_rcm(self.world.measured_js(self.name)[0]) @ RIG_TIP_TO_TOOL_TIP

    def local_measured_cp(self) -> Pose:
        """dVRK local/measured_cp: the RCM-frame pose (no base frame is configured on a PSM)."""
        return self.measured_cp()

    def measured_cp_world(self) -> Pose:
        """The measured tool-tip pose (measured_cp's) in the rig's world frame."""
        T = self.world.arms[self.name].rcm_world @ self._tool_tip()
        return Pose(self.clock.now(), T[:3, 3].copy(), T[:3, :3].copy(), "world")

    def body_measured_cf(self) -> Wrench:
        """Tip wrench from the measured efforts, in the tip frame (dVRK body/measured_cf)."""
        q, _, effort = self.world.measured_js(self.name)
        f, m = body_wrench_from_effort(q, effort)
        return Wrench(self.clock.now(), f, m, f"{self.name}_tip")

    # -- commanding -------------------------------------------------------------------
    def servo_jp(self, position, velocity=None) -> None:
        """Position set-point for the joint PID now (rad, rad, m); cancels a move_jp."""
        q = _joints(position, "servo_jp")
        dq = None if velocity is None or len(velocity) == 0 else _joints(velocity, "servo_jp velocity")
        self._trajectory = self._goal = None
        self.powered = True
        self.world.servo_jp(self.name, q, dq)

    def servo_jf(self, effort) -> None:
        """Joint efforts (N m, N m, N) straight to the drives (saturated at the drive limit)."""
        tau = _joints(effort, "servo_jf")
        self._trajectory = self._goal = None
        self.powered = True
        self.world.servo_jf(self.name, tau)

    def move_jp(self, position, wait: bool = True, timeout: float = 10.0) -> bool:
        """Move to joint `position` along a smooth profile within the velocity limits.

        wait=False: start and return True at once (the clock's ticks advance the move).
        wait=True: tick the clock until the arm is within ARRIVAL_TOLERANCE of the goal and
        at rest, or `timeout` seconds of clock time passed (then False; the move goes on).
        """
        goal = _joints(position, "move_jp")
        problem = self.limits.violation(goal)
        if problem:
            raise ValueError(f"{self.name} move_jp goal refused: {problem}")
        start = self.world.setpoint_js(self.name)[0] if self.world.mode(self.name) == "position" \
            else self.world.measured_js(self.name)[0]
        self._goal = goal
        self.powered = True
        self._trajectory = JointTrajectory.plan(start, goal, self.clock.now(),
                                                self.velocity_ratio * self.limits.dq_max,
                                                self.acceleration_ratio * DDQ_MAX)
        self._command_trajectory(self.clock.now())
        if not wait:
            return True
        return self.wait_move(timeout)

    def wait_move(self, timeout: float = 10.0) -> bool:
        """Tick the clock until the current move_jp arrived (True) or `timeout` s passed."""
        t_end = self.clock.now() + timeout
        while not self.arrived():
            if self.clock.now() >= t_end - 1e-12:
                return False
            self.clock.tick()
        return True

    def arrived(self) -> bool:
        """True when no move_jp is under way or its goal is reached and the arm is at rest."""
        if self._goal is None:
            return True
        if self._trajectory is not None:
            return False
        q, dq, _ = self.world.measured_js(self.name)
        return bool(np.all(np.abs(q - self._goal) <= ARRIVAL_TOLERANCE)
                    and np.all(np.abs(dq) <= REST_VELOCITY))

    def is_moving(self) -> bool:
        """True while a move_jp trajectory is being generated."""
        return self._trajectory is not None

    def hold(self) -> None:
        """Hold the present encoder position under the PID, at rest (the safe state)."""
        self._trajectory = self._goal = None
        self.powered = True
        self.world.hold(self.name)

    def published_rate(self) -> float:
        """0.0: in process, every tick of the rig clock has a fresh sample (drivers.interfaces.Arm)."""
        return 0.0

    @property
    def supports_servo_ci(self) -> bool:
        """The in-process arm takes efforts and positions, not a Cartesian impedance."""
        return False

    # -- console ----------------------------------------------------------------------
    def power_on(self) -> None:
        """Enable the drives: the arm holds where it is."""
        if not self.powered or self.world.mode(self.name) == "off":
            self.hold()
        self.powered = True

    def power_off(self) -> None:
        """Disable the drives (the arm falls under gravity, braked only by friction)."""
        self._trajectory = self._goal = None
        self.powered = False
        self.world.power_off(self.name)

    def home(self, wait: bool = True, timeout: float = 10.0) -> bool:
        """Power on and move to the arm's home position (the simulated arm's q0)."""
        self.power_on()
        return self.move_jp(self.home_position, wait=wait, timeout=timeout)

    # -- device side ------------------------------------------------------------------
    def _command_trajectory(self, t: float) -> None:
        traj = self._trajectory
        # The set-point for the step about to run is the profile one period ahead.
        q, dq = traj.sample(t + self.world.dt)
        self.world.servo_jp(self.name, q, dq)
        if t + self.world.dt >= traj.end():
            self._trajectory = None

    def _on_tick(self, t: float) -> None:
        if self._trajectory is not None:
            self._command_trajectory(t)
