"""Cooperative object manipulation with force tracking (thesis 6.3, 7.7).

One master PSM follows a Cartesian trajectory under position control (servo_jp through
the inverse kinematics); every slave runs the impedance controller of 7.3 and follows
the master's increments (eq. 6.2, in the world frame) while its target is pushed along
the object vector to track the tension (eq. 7.10-7.12):

    x_t = x_d + u x_f,     u = (x_slave - x_master) / |x_slave - x_master|
    x_f <- x_f + dt (k_i (h_d - h_e) - k_damp dh_e/dt)     outside a deadband

The thesis' x_f update is a pure integrator (K_f = k_i dt); its 1-2 N start-up transient
came from the missing damping, which here is the rate term k_damp dh_e/dt on the filtered
tension, and the tension set-point is ramped up with a minimum-jerk profile once the
object is taut (a slack object is first taken up at a set tip speed).
Slaves add the master's measured lag behind its plan (position and velocity) to their own
plan. On a stiff string the slave also gets a proportional tension feedback k_fp (F_d - F)
along the object (see `preset`).
With three arms the object is a triangle. Each slave tracks the tension of its element
with the master, moving away from the master; the pull of the element between the two
slaves is measured too and fed forward into the slave's target (its tension divided by
the impedance stiffness, along that element), so the impedance does not yield to it, and
that element's tension error is integrated into a second offset along it, half by each
of its slaves.
User increments (keyboard, ROS) are targets the applied offsets slew toward.

The controller sees only measurements (joint states, tension samples); it never reads
the simulated world. It returns, per arm, a position command or an effort command.
"""

from __future__ import annotations

import numpy as np

from rig.control.arm_command import ArmCommand, CommandKind
from rig.control.controllers import FeedforwardModel, Impedance, StickSlipCompensation
from rig.control.cooperative_gains import (ArmImpedanceGains, ForceLoop, ImpedanceGains, Mode, PositionForceLoop,
                                           SlaveControl, arm_preset, choice, preset)
from rig.control.cooperative_plan import Motion, Plan, UserOffsets, euler_xyz, min_jerk
from rig.control.master_lag import JointEstimate, master_lag
from rig.control.object_elements import ObjectElements, PairOffsets
from rig.control.slack_take_up import SlackTakeUp
from rig.control.slave_strategies import SlaveInputs, strategy_for
from rig.control.tension_estimate import TensionEstimate
from rig.model import psm_kinematics as K

__all__ = ["ArmCommand", "ArmImpedanceGains", "CommandKind", "CooperativeController", "ForceLoop",
           "ImpedanceGains", "Mode", "Motion", "PositionForceLoop", "SlaveControl", "arm_preset", "euler_xyz",
           "min_jerk", "preset"]


class CooperativeController:
    """Master in position control, slaves in impedance control with tension tracking.

    `rcm_frames`: each arm's RCM frame in the world (4x4, from the registration).
    `models`: a FeedforwardModel per slave (identified model, or nominal).
    `friction`: a StickSlipCompensation per slave.
    `elements`: the object's elements as pairs of arm names (the load cells' order).

    The parts: the plan and the user's increments (`plan`, `offsets`), the joints'
    filters (`joints`), the tension estimate (`estimate`), the slack take-up and the
    set-point ramp (`take_up`), the object's elements and the slave-slave offsets
    (`elements`, `pairs`), and one slave strategy (`strategy`) per `Mode` and
    `SlaveControl`. Every piece of state is made here and restarted by `start`.
    """

    def __init__(self, arms: list[str], master: str, rcm_frames: dict[str, np.ndarray],
                 models: dict[str, FeedforwardModel], friction: dict[str, StickSlipCompensation],
                 elements: list[tuple[str, str]], force: float, dt: float = 1e-3,
                 motion: Motion | None = None, loop: ForceLoop | None = None,
                 gains: ImpedanceGains | None = None, force_noise: float = 0.02,
                 object_stiffness: float = 2450.0, follow_measured_master: bool = True,
                 mode: str = "impedance", position_loop: PositionForceLoop | None = None,
                 slew_translation: float = 0.01, slew_rotation: float = 0.1, slew_force: float = 2.0,
                 slave_control: str = "effort", arm_gains: ArmImpedanceGains | None = None):
        if master not in arms:
            raise ValueError(f"master {master!r} is not among the arms {arms}")
        self.mode = choice(Mode, mode, "mode")
        self.slave_control = choice(SlaveControl, slave_control, "slave_control")
        self.arm_gains = arm_gains or ArmImpedanceGains()
        self.position_loop = position_loop or PositionForceLoop()
        self.arms = list(arms)
        self.master = master
        self.slaves = [a for a in arms if a != master]
        self.dt = dt
        self.R = {a: rcm_frames[a][:3, :3].copy() for a in arms}
        self.p = {a: rcm_frames[a][:3, 3].copy() for a in arms}
        self.elements = ObjectElements(elements, master, self.slaves)
        self.force = float(force)
        self.loop = loop or ForceLoop()
        self.object_stiffness = float(object_stiffness)
        # Slaves follow the master's measured motion (its PID lags its command; following
        # the command would stretch the object by that lag) rather than its set-point.
        self.follow_measured_master = follow_measured_master
        self._init_impedance(gains or ImpedanceGains(), models, friction)
        self.plan = Plan(motion or Motion(), self.arms)
        self.offsets = UserOffsets(slew_translation, slew_rotation, slew_force)
        self.joints = JointEstimate(self.arms, dt)
        self.estimate = TensionEstimate(len(self.elements), dt, force_noise)
        self.take_up = SlackTakeUp(self.slaves, self.force, self.loop.ramp_time, self.loop.contact,
                                   scale_ramp=self.slave_control == SlaveControl.ARM)
        self.pairs = PairOffsets()
        self.strategy = strategy_for(self.mode, self.slave_control)
        self.x_f = {s: 0.0 for s in self.slaves}   # m: each slave's offset along the object
        self.k_i = {s: self.loop.k_i for s in self.slaves}
        self.k_damp = self.loop.k_damp
        self.x_f_limit = self.loop.x_f_limit
        self.force_setpoint = 0.0
        self.set_point_rate = 0.0   # N/s
        self.dt_tick = dt           # s since the last step (see step)
        self._t_previous: float | None = None

    def _init_impedance(self, g: ImpedanceGains, models, friction) -> None:
        arm = self.slave_control == SlaveControl.ARM
        self.kp_along = self.arm_gains.kp_along if arm else float(np.mean(g.Kp))
        # proportional tension feedback (dimensionless), with the arm's own inertia only;
        # none in the arm (a measured force fed back at the rate heard over the wire would
        # drive the arm-object mode)
        self.k_fp = float(g.force_feedback) if g.Md is None and not arm else 0.0
        self.kp_across = None if arm else g.Kp_across
        self.impedance = {s: Impedance(models[s], friction[s], None if g.Md is None else g.Md.copy(),
                                       g.Kp.copy(), g.Kd.copy(), g.damping_ratio,
                                       float(np.max(g.Kp)) + self.object_stiffness * (1.0 + self.k_fp))
                          for s in self.slaves}

    # -- what the procedure and its report read -------------------------------------------
    @property
    def t0(self) -> float | None:
        return self.plan.t0

    @property
    def motion(self) -> Motion:
        return self.plan.motion

    @property
    def joint_filter(self):
        return self.joints.filters

    @property
    def force_filter(self):
        return self.estimate.filter

    @property
    def tension(self) -> np.ndarray:
        return self.estimate.tension

    @property
    def tension_rate(self) -> np.ndarray:
        return self.estimate.tension_rate

    @property
    def raw_tension(self) -> np.ndarray:
        return self.estimate.raw_tension

    @property
    def blind(self) -> bool:
        return self.estimate.blind

    # the user's increments (procedures.cooperative_live sets the targets)
    force_offset = property(lambda self: self.offsets.force_offset,
                            lambda self, v: setattr(self.offsets, "force_offset", v))
    offset_translation = property(lambda self: self.offsets.translation,
                                  lambda self, v: setattr(self.offsets, "translation", v))
    offset_rotation = property(lambda self: self.offsets.rotation,
                               lambda self, v: setattr(self.offsets, "rotation", v))
    applied_force_offset = property(lambda self: self.offsets.applied_force)
    applied_translation = property(lambda self: self.offsets.applied_translation)
    applied_rotation = property(lambda self: self.offsets.applied_rotation)
    slew_translation = property(lambda self: self.offsets.slew_translation)   # m/s
    slew_rotation = property(lambda self: self.offsets.slew_rotation)         # rad/s
    slew_force = property(lambda self: self.offsets.slew_force)               # N/s

    # -- frames -------------------------------------------------------------------------
    def tip_world(self, arm: str, q: np.ndarray) -> np.ndarray:
        return self.p[arm] + self.R[arm] @ K.tip_in_rcm(q)

    def to_rcm(self, arm: str, x_world: np.ndarray) -> np.ndarray:
        return self.R[arm].T @ (x_world - self.p[arm])

    def desired(self, t: float, targets: bool = False
                ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
        """World-frame desired tip positions, velocities and accelerations (eq. 6.2-6.3), with
        the user offsets applied so far, or with their targets (`targets=True`: what a
        limit check of the rest of the plan needs)."""
        return self.plan.desired(t, self.offsets, targets)

    def tracked_tensions(self) -> dict[str, float]:
        """Each slave's tracked tension (N) in the estimate."""
        return {s: self.elements.tracked_mean(self.estimate.tension, s) for s in self.slaves}

    # -- life cycle ---------------------------------------------------------------------
    def start(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray], tension: np.ndarray,
              stamps: dict[str, float] | None = None, tension_t: np.ndarray | None = None) -> None:
        """Start the plan at `t` from the arms at `q`, `dq` and the object at `tension`;
        `stamps`, `tension_t`: the times those samples were taken (see `step`)."""
        self._t_previous = None
        self.dt_tick = self.dt
        if self.joints.start(t, q, dq, stamps):
            self.estimate.filter.prepare_intervals()
        self.estimate.start(tension, tension_t)
        self.plan.start(t, {a: self.tip_world(a, q[a]) for a in self.arms})
        self.take_up.start(t, tension, {s: self.elements.tracked_mean(np.asarray(tension), s) for s in self.slaves},
                           take_up=self.mode == Mode.IMPEDANCE and self.force > self.loop.contact)
        self.k_i = {s: self._force_gain(s, q[s]) for s in self.slaves}
        self.k_damp = self.loop.k_damp
        # x_f must be able to reach the ceiling tension through the impedance spring
        self.x_f_limit = max(self.loop.x_f_limit, 2.0 * self.force / self.kp_along + 0.01)
        self.pairs.reset()
        self.strategy.reset()
        if self.mode == Mode.IMPEDANCE and self.slave_control == SlaveControl.EFFORT:
            # Pre-load each slave's impedance with the tension already on the object, so that
            # switching the slave to effort control does not let the object pull it in.
            # (In the arm the set-point tension is a force feedforward: no pre-load.)
            for s in self.slaves:
                held = self.elements.tracked_mean(self.take_up.initial_element_tension, s)
                self.x_f[s] = held / self.kp_along

    def _force_gain(self, slave: str, q: np.ndarray) -> float:
        """Integral gain of the tension loop, kept a factor `bandwidth_ratio` below the slave's
        mechanical mode against the object (sqrt((Kp + K_obj) / Lambda_u)): faster than that
        and the loop drives the arm-object oscillation."""
        imp = self.impedance[slave]
        tips = {**self.plan.x0, slave: self.tip_world(slave, q)}
        u_world = self.elements.outward(slave, tips)
        u = self.R[slave].T @ u_world
        if self.slave_control == SlaveControl.ARM:
            from rig.control.arm_impedance import cartesian_inertia

            Lam = cartesian_inertia(imp.model.mass_matrix(q), K.tip_jacobian_rcm(q), u) * np.eye(3)
        elif imp.Md is None:
            J = K.tip_jacobian_rcm(q)
            Lam = np.linalg.inv(J @ np.linalg.inv(imp.model.mass_matrix(q)) @ J.T)
        else:
            Lam = np.diag(imp.Md)
        kp = self.kp_along
        # the object's stiffness along u: each element contributes K (u . its direction)^2
        dirs = self.elements.neighbour_directions(slave, tips)
        k_obj = self.object_stiffness * sum(float(u_world @ d) ** 2 for d in dirs)
        # the tension feedback stiffens the arm-object mode by (1 + k_fp) ...
        omega = np.sqrt((kp + k_obj * (1.0 + self.k_fp)) / float(u @ Lam @ u))
        # ... and divides d(tension of the tracked element)/d(x_f), the impedance in series
        # with the object, by as much: the integral gain grows with it, under the same cap
        series = self.object_stiffness * kp / (kp + k_obj * (1.0 + self.k_fp))
        # and a tenth of the loop's own rate: over the wire the tension and the joints are
        # a tick or two old when the loop acts (at 100 Hz, 10-20 ms), which a crossover of
        # 0.1 / dt rad/s loses 0.1-0.2 rad of phase to
        return float(min(self.loop.k_i * (1.0 + self.k_fp), omega / (self.loop.bandwidth_ratio * series),
                         self.loop.tick_gain / (self.dt * series)))

    def force_target(self, t: float) -> float:
        """The tension set-point (N) at `t`: the slack take-up's, then its ramp, plus the user's offset."""
        return self.take_up.set_point(t, self.offsets.applied_force)

    # -- one cycle ----------------------------------------------------------------------
    def step(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray],
             tension: np.ndarray | None, blind: bool = False, stamps: dict[str, float] | None = None,
             tension_t: np.ndarray | None = None) -> dict[str, ArmCommand]:
        """One control cycle. `tension`: newest sample per object element, or None if no new one.

        `blind`: the newest tension sample is too old to act on (the caller judges its age
        against the load cell's frame period). The force loop then holds
        (rig.control.tension_estimate): no offset moves (x_f, the pairs' offsets, the slack
        take-up, the position-mode steps); the impedance keeps the slaves where their
        targets were and the master keeps to its plan. Acting on a stale tension instead
        winds the offsets up against a force that is no longer measured: samples that
        stopped reaching the loop for 0.3 s during the take-up let the spring be stretched
        to 9 N while the controller read 0 N, and the effort jumped past the ceiling when
        they resumed.

        `stamps` (s, per arm) and `tension_t` (s, per element): when the joint and tension
        samples were taken. Given, the filters step by the samples' own intervals, and the
        loop's integrators by the time since the last step. Without them every step is
        `dt` after the last (a loop in sim time).
        """
        if self.plan.t0 is None:
            raise RuntimeError("start() the controller first")
        self.dt_tick = self._tick_length(t, stamps)
        qf, dqf = self.joints.update(t, q, dq, stamps)
        hold = self.estimate.update(tension, tension_t, blind, self.dt_tick,
                                    timed=tension_t is not None or stamps is not None)
        self.offsets.slew(self.dt_tick)
        xd, vd, ad = self.desired(t)
        self._advance_set_point(t)
        tips = {a: self.tip_world(a, qf[a]) for a in self.arms}
        commands = {self.master: self._master_command(xd, vd)}
        if self.follow_measured_master:
            shift, v_shift = master_lag(self.master, t, stamps is not None, self.joints, qf, dqf, tips,
                                        self.R[self.master], (xd, vd), self.desired)
        for s in self.slaves:
            if self.follow_measured_master:
                xd[s] = xd[s] + shift
                vd[s] = vd[s] + v_shift
            x = SlaveInputs(t, xd[s], vd[s], ad[s], qf[s], dqf[s], tips, hold, self.elements.outward(s, tips),
                            self.elements.tracked_mean(self.tension, s),
                            self.elements.tracked_mean(self.tension_rate, s))
            commands[s] = self.strategy.command(self, s, x)
        return commands

    def _tick_length(self, t: float, stamps) -> float:
        """The integrators' step: the time since the last step, within a quarter and four
        loop periods (a longer gap is a held process: its tension is judged by `blind`)."""
        t_last = self._t_previous
        elapsed = self.dt if (stamps is None or t_last is None or t <= t_last) else t - t_last
        return self.dt if abs(elapsed - self.dt) <= 1e-6 * self.dt else min(max(elapsed, 0.25 * self.dt),
                                                                             4.0 * self.dt)

    def _advance_set_point(self, t: float) -> None:
        """The set-point at `t` and its rate on the loop's own clock (a held tick is longer than dt)."""
        previous, t_previous = self.force_setpoint, self._t_previous
        self.force_setpoint = self.force_target(t)
        self.set_point_rate = (0.0 if t_previous is None or t <= t_previous
                               else (self.force_setpoint - previous) / (t - t_previous))
        self._t_previous = t

    def _master_command(self, xd: dict, vd: dict) -> ArmCommand:
        """The master: Cartesian position control through the inverse kinematics."""
        m = self.master
        q_m = K.ik_rcm(self.to_rcm(m, xd[m]))
        dq_m = np.linalg.solve(K.tip_jacobian_rcm(q_m), self.R[m].T @ vd[m])
        return ArmCommand(CommandKind.POSITION, q=q_m, dq=dq_m)
