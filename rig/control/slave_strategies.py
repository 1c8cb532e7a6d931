"""How a slave tracks the tension: one strategy per way of running it.

- `EffortSlave` (Mode.IMPEDANCE, SlaveControl.EFFORT): this loop closes the slave's
  impedance (7.3) and commands efforts; its target x_t = x_d + u x_f moves along the
  object to track the tension (eq. 7.10-7.12, plus damping on the tension's rate).
- `ArmSlave` (Mode.IMPEDANCE, SlaveControl.ARM): the arm closes the impedance in its
  servo loop (the dVRK's servo_ci); this loop moves its goal and feeds the set-point
  forward (force and stretch), so x_f only corrects what the plan does not know.
- `PositionSlave` (Mode.POSITION): thesis 7.7.3, fixed steps of a position target while
  the tension error is outside a deadband.

Each gets the controller (`rig.control.cooperative_controller.CooperativeController`),
whose parts hold the state, and the slave's inputs for this cycle (`SlaveInputs`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.control.arm_command import ArmCommand, CommandKind
from rig.control.cooperative_gains import Mode, SlaveControl
from rig.model import psm_kinematics as K


@dataclass
class SlaveInputs:
    """One slave's cycle: its plan (world: m, m/s, m/s^2), filtered joints, every arm's tip,
    whether the tension estimate holds, the outward direction u and the tension it tracks."""

    t: float
    xd: np.ndarray
    vd: np.ndarray
    ad: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tips: dict[str, np.ndarray]
    hold: bool
    u: np.ndarray
    tension: float        # N, the mean of its tracked elements
    tension_rate: float   # N/s


def _tracking_rate(c, s: str, x: SlaveInputs, feed_set_point: bool) -> float:
    """x_f's rate (m/s) tracking the set-point: the integral of the error outside the
    deadband and damping on the tension's rate (with `feed_set_point`, on the error's:
    the set-point's own rise is fed forward and damping it would fight every ramp)."""
    error = c.force_setpoint - x.tension
    damped = x.tension_rate - (c.set_point_rate if feed_set_point else 0.0)
    rate = -c.k_damp * damped
    if abs(error) > c.loop.deadband:
        rate += c.k_i[s] * (error - np.sign(error) * c.loop.deadband)
    return rate


def _advance(c, s: str, rate: float) -> None:
    """x_f over this cycle at `rate`, within its ceiling."""
    c.x_f[s] = min(max(float(c.x_f[s] + c.dt_tick * rate), -c.x_f_limit), c.x_f_limit)


def _integrate_pair(c, s: str, k: int, hold: bool) -> None:
    """The slave-slave element k's tension error into slave s's offset along it; none
    while any slave is slack or the force loop holds."""
    if c.take_up.any_slack or hold:
        return
    c.pairs.integrate(s, k, c.force_setpoint - float(c.tension[k]), float(c.tension_rate[k]), c.k_i[s],
                      c.loop.deadband, c.loop.k_damp, c.dt_tick, c.x_f_limit)


class PositionSlave:
    """Thesis 7.7.3: the target steps along the object every period while the error is
    outside the deadband (not while the tension estimate holds)."""

    def __init__(self):
        self.next_step = 0.0   # s: when the slaves step next

    def reset(self) -> None:
        self.next_step = 0.0

    def command(self, c, s: str, x: SlaveInputs) -> ArmCommand:
        pl = c.position_loop
        error = c.force_setpoint - x.tension
        if x.t + 1e-12 >= self.next_step:
            if abs(error) > pl.deadband and not x.hold:
                c.x_f[s] = float(np.clip(c.x_f[s] + pl.step * np.sign(error), -c.x_f_limit, c.x_f_limit))
            if s == c.slaves[-1]:
                self.next_step = x.t + pl.period
        x_rcm = c.to_rcm(s, x.xd + 0.0 + x.u * c.x_f[s])
        q = K.ik_rcm(x_rcm)
        dq = np.linalg.solve(K.tip_jacobian_rcm(q), c.R[s].T @ x.vd)
        return ArmCommand(CommandKind.POSITION, q=q, dq=dq)


class EffortSlave:
    """The slave's impedance closed here; efforts commanded (servo_jf)."""

    def reset(self) -> None:
        pass

    def command(self, c, s: str, x: SlaveInputs) -> ArmCommand:
        if x.hold:
            rate = 0.0
        elif c.take_up.slack[s]:
            # a slack object is taken up at a set tip speed outward
            if x.tension >= c.loop.contact:
                c.take_up.taut(s, x.t, c.tracked_tensions())
            v_out = float(c.R[s] @ (K.tip_jacobian_rcm(x.q) @ x.dq) @ x.u - x.vd @ x.u)
            rate = c.loop.take_up_gain * (c.loop.take_up_speed - v_out)
        else:
            rate = _tracking_rate(c, s, x, feed_set_point=False)
        _advance(c, s, rate)
        return ArmCommand(CommandKind.EFFORT, effort=self._effort(c, s, x, x.xd + x.u * c.x_f[s]))

    @staticmethod
    def _effort(c, s: str, x: SlaveInputs, x_t: np.ndarray) -> np.ndarray:
        """The impedance's joint efforts toward the target `x_t` (world), with the pull of the
        slave-slave elements fed forward and the tension feedback k_fp."""
        if c.kp_across is not None:
            u_r = c.R[s].T @ x.u
            c.impedance[s].Kp = c.kp_across * np.eye(3) + (c.kp_along - c.kp_across) * np.outer(u_r, u_r)
        for k in c.elements.pairs[s]:
            # the slave-slave element: its pull is fed forward (the impedance does not yield
            # to it), and its tension error integrated into a second offset along it
            w = c.elements.direction(k, s, x.tips)
            _integrate_pair(c, s, k, x.hold)
            x_t = x_t + w * (c.tension[k] / c.kp_along + c.pairs.get(s, k))
        # the force the tip exerts on the object: each element's tension, pointing from the
        # neighbour to this tip (outward)
        h_world = np.zeros(3)
        for k in c.elements.mine[s]:
            d = c.elements.span(k, s, x.tips)
            h_world += c.tension[k] * d / max(np.linalg.norm(d), 1e-9)
        R = c.R[s]
        f_extra = None
        if c.k_fp and c.elements.tracked[s] and not c.take_up.slack[s]:
            # on the newest raw sample: the Kalman filter's lag, not the sensor noise
            # (0.02 N times k_fp, filtered by the arm's inertia), limits this gain
            error_fb = c.force_setpoint - c.elements.tracked_mean(c.raw_tension, s)
            f_extra = R.T @ (c.k_fp * error_fb * x.u)
        return c.impedance[s](x.q, x.dq, R.T @ (x_t - c.p[s]), R.T @ x.vd, R.T @ x.ad, R.T @ h_world, f_extra)


class ArmSlave:
    """The slave's impedance run by the arm (servo_ci); this loop moves its goal.

    A slack object is taken up by force: the arm pushes the slave outward with the take-up
    force and no spring along the object, so it arrives at the object at that tension,
    below the set-point, however late the loop sees it (taken up by position, a stiff
    string overshot by K_obj x speed x the loop's delay: 20 kN/m x 10 mm/s x 20 ms = 4 N).
    """

    def reset(self) -> None:
        pass

    def command(self, c, s: str, x: SlaveInputs) -> ArmCommand:
        if c.take_up.slack[s]:
            along = float(x.u @ (x.tips[s] - x.xd))
            if x.hold or x.tension < c.loop.contact:
                # no new tension, or still slack: keep taking up by force
                return self._goal(c, s, x, x.xd + x.u * along, x.vd, take_up=True)
            # taut: the spring and the set-point's stretch start from here
            c.x_f[s] = along
            c.take_up.initial_element_tension = c.tension.copy()
            c.take_up.taut(s, x.t, c.tracked_tensions())
            rate = 0.0
        elif x.hold:
            rate = 0.0
        else:
            rate = _tracking_rate(c, s, x, feed_set_point=True)
        _advance(c, s, rate)
        # the set-point's stretch is motion the arm must make: its damping and friction are
        # fed forward with the plan's (x_f's rate is not: fed back through the damping, the
        # loop's own correction limit-cycled)
        v_t = x.vd + x.u * (c.set_point_rate / c.object_stiffness)
        return self._goal(c, s, x, x.xd + x.u * c.x_f[s], v_t)

    def _goal(self, c, s: str, x: SlaveInputs, x_t: np.ndarray, v_d: np.ndarray,
              take_up: bool = False) -> ArmCommand:
        """The goal of the arm's impedance (see rig.control.arm_impedance): the target with the
        set-point's stretch, the model's feedforward of the planned motion, the set-point
        tension as a force along each element the slave holds."""
        R = c.R[s]
        J = K.tip_jacobian_rcm(x.q)
        v_r, a_r, u_r = R.T @ v_d, R.T @ x.ad, R.T @ x.u
        dq_plan = np.linalg.solve(J, v_r)
        imp = c.impedance[s]
        # friction of the planned motion only: the measured velocity reaches this loop a tick
        # or two late over the wire, and compensation on it acts after the slave has already
        # broken away or stuck
        tau = imp.model(x.q, dq_plan, np.linalg.solve(J, a_r)) + imp.friction(dq_plan, 0.0, dq_plan)
        # the object's stretch for the set-point is fed forward too (its configured
        # stiffness): with the force alone, the spring would take up part of every change
        # of the set-point (K_obj / (Kp + K_obj) of it reaches the object) and x_f would
        # have to integrate the rest
        held = c.elements.tracked_mean(c.take_up.initial_element_tension, s)
        target = x_t if take_up else x_t + x.u * ((c.force_setpoint - held) / c.object_stiffness)
        f_world = np.zeros(3)
        for k in c.elements.mine[s]:
            w = c.elements.direction(k, s, x.tips)
            f_world += c.force_setpoint * w
            if k not in c.elements.tracked[s]:
                # the slave-slave element: its offset and half its set-point's stretch
                _integrate_pair(c, s, k, x.hold)
                target = target + w * (c.pairs.get(s, k) + 0.5 * (c.force_setpoint
                                                                  - c.take_up.initial_element_tension[k])
                                       / c.object_stiffness)
        if take_up:
            f_world = x.u * max(c.loop.contact, min(c.loop.take_up_force, 0.6 * c.force))
        tau = tau + J.T @ (R.T @ f_world)
        stiffness = np.array([0.0 if take_up else c.arm_gains.kp_along, c.arm_gains.kp_across,
                              c.arm_gains.kp_across])
        return ArmCommand(CommandKind.IMPEDANCE, target=R.T @ (target - c.p[s]), velocity=v_r, u=u_r,
                          stiffness=stiffness, damping=self._damping(c, s, x, J, u_r, stiffness),
                          feedforward=tau)

    @staticmethod
    def _damping(c, s: str, x: SlaveInputs, J: np.ndarray, u_r: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
        """N s/m on the axes of force_frame(u): `damping_ratio` against the arm's Cartesian
        inertia and the spring plus the object's stiffness along each axis."""
        from rig.control.arm_impedance import cartesian_inertia, force_frame

        R = c.R[s]
        Rf = force_frame(u_r)
        M = c.impedance[s].model.mass_matrix(x.q)
        dirs = [R.T @ d for d in c.elements.neighbour_directions(s, x.tips)]
        damping = np.empty(3)
        for i in range(3):
            axis = Rf[:, i]
            k_obj = c.object_stiffness * sum(float(axis @ d) ** 2 for d in dirs)
            damping[i] = 2.0 * c.arm_gains.damping_ratio * np.sqrt((stiffness[i] + k_obj) * cartesian_inertia(M, J, axis))
        return damping


def strategy_for(mode: Mode, slave_control: SlaveControl):
    """The slave strategy of a mode and who closes the impedance."""
    if mode == Mode.POSITION:
        return PositionSlave()
    return ArmSlave() if slave_control == SlaveControl.ARM else EffortSlave()
