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

from dataclasses import dataclass, field

import numpy as np

from rig.control.controllers import FeedforwardModel, Impedance, KalmanDifferentiator, StickSlipCompensation
from rig.model import psm_kinematics as K


def _mean_of(values: np.ndarray, indices: list[int]) -> float:
    """Mean of values[indices] (0 for none): np.mean's dispatch costs more than the sum of the
    one or two elements a control step averages."""
    return float(sum(values[k] for k in indices) / len(indices)) if indices else 0.0


def min_jerk(s: float) -> tuple[float, float, float]:
    """Minimum-jerk profile on [0, 1]: (position, d/ds, d2/ds2)."""
    s = min(max(s, 0.0), 1.0)
    p = 10 * s**3 - 15 * s**4 + 6 * s**5
    v = 30 * s**2 - 60 * s**3 + 30 * s**4
    a = 60 * s - 180 * s**2 + 120 * s**3
    return p, v, a


def euler_xyz(angles: np.ndarray) -> np.ndarray:
    """Rotation for x, y, z Euler angle increments (rad): R = Rz Ry Rx."""
    a, b, c = angles
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass
class ForceLoop:
    """Gains of the tension loop (eq. 7.12 plus damping); SI units."""

    k_i: float = 0.08          # m/(N s): x_f rate per newton of tension error
    k_damp: float = 0.0015     # m/N: x_f rate per N/s of tension rate (the damping term)
    deadband: float = 0.02     # N: no integration inside it
    ramp_time: float = 1.0     # s: minimum-jerk ramp of the set-point from the initial tension
    # A slack object (tension below `contact` N) is taken up with the slave's tip moving
    # outward at `take_up_speed` (m/s; x_f integrates the speed error with `take_up_gain`,
    # 1/s) before the set-point ramp starts: integrating the tension error over the slack
    # would arrive at the object fast with the target far beyond it (2 N overshoot on a string).
    contact: float = 0.5
    take_up_speed: float = 0.01
    take_up_gain: float = 10.0
    take_up_force: float = 3.0   # N (at most 0.6 of the set-point): the arm takes a slack object up by this force
    x_f_limit: float = 0.03    # m: |x_f| ceiling (the object cannot need more)
    bandwidth_ratio: float = 3.0  # the loop stays this factor below the arm-object mode
    tick_gain: float = 0.1        # and its crossover at most this over one loop period


@dataclass
class ImpedanceGains:
    Md: np.ndarray | None = None   # kg; None: the arm's own Cartesian inertia (see Impedance)
    Kp: np.ndarray = field(default_factory=lambda: np.array([400.0, 400.0, 400.0]))  # N/m, along the object
    # N/m across the object; None: Kp in every direction. A slave soft along the object but
    # stiff across it holds its place against model and gravity errors without stiffening
    # the force loop.
    Kp_across: float | None = None
    Kd: np.ndarray = field(default_factory=lambda: np.array([20.0, 20.0, 20.0]))  # N s/m (with Md)
    damping_ratio: float | None = 0.7   # with Md None: ratio against Kp + the object's stiffness
    # With Md None: proportional tension feedback k_fp (F_d - F) along the object, added to
    # the impedance force. It divides a force disturbance on the slave (friction, model
    # error) by 1 + k_fp below the arm-object mode, which it stiffens by as much (the
    # damping is designed against Kp + (1 + k_fp) K_obj).
    force_feedback: float = 0.0


@dataclass
class ArmImpedanceGains:
    """A slave's impedance run by the arm (the dVRK's servo_ci): a spring `kp_along` (N/m)
    along the object and `kp_across` across it, damped at `damping_ratio` against the
    arm's Cartesian inertia along each axis and the spring plus the object's stiffness."""

    kp_along: float = 400.0
    kp_across: float = 1000.0
    damping_ratio: float = 0.7


@dataclass
class PositionForceLoop:
    """Thesis 7.7.3: both arms in position control; a slave steps its target by `step` (m)
    every `period` (s) while the tension error is outside `deadband` (N).

    The thesis stepped at 500 Hz on the real dVRK. The simulated joint PIDs settle in tens
    of milliseconds, and stepping every 2 ms outruns them (every deadband then limit-cycles
    by several newtons); at 50 Hz the thesis' finding shows: a 0.2 mm step moves the spring's
    tension by about 0.5 N, so a deadband narrower than half a step hunts and a wider one
    settles."""

    step: float = 0.0002
    period: float = 0.02
    deadband: float = 0.4


def preset(kind: str) -> tuple[ImpedanceGains, bool]:
    """Impedance gains and whether slaves follow the master's measured motion, per object.

    A compliant spring (~2.5 kN/m) tolerates feeding the measured force back with a light
    desired inertia (0.5 kg), which gives the tension loop bandwidth. A string (>= 20 kN/m)
    does not: a desired inertia of 0.35 kg limit-cycled (the sampled, filtered force arrives
    too late for an arm-object mode above 200 rad/s). There the slave keeps its own inertia
    and gets a moderate proportional tension feedback on the raw samples instead (k_fp 10,
    which divides friction and model disturbances by 11). Both follow the master's measured
    motion: the master's PID lags its plan and slips out of static friction in steps, which
    a slave following the plan would pass into the object (on a 20 kN/m string, following
    the plan gave 0.24 N while moving, following the measurement 0.17 N; at 100 kN/m
    0.39 N and 0.21 N).
    """
    if kind == "spring":
        # Md 1 kg: 0.5 kg gave 0.10 N in-process, but a control loop held up by the machine
        # (over the wire, two CPU burners: holds of 10-20 ms) rang on joint 2 up to the
        # effort ceiling; in-process at 500 Hz with the measured joints a tick late and
        # holds of up to 7 periods on 30 % of the ticks, 0.5 and 0.75 kg aborted and 1 kg
        # held (0.14-0.18 N; holds of up to 11 periods on 15 %: 0.21-0.35 N).
        return ImpedanceGains(Md=np.full(3, 1.0), Kp=np.full(3, 400.0), damping_ratio=0.7), True
    if kind == "string":
        # Kp 200 N/m: of 50-800 N/m this gave the smallest error while moving (a softer
        # slave lags the master, a stiffer one passes the master's lag into the string).
        # k_fp 10: of 0-20 tried (15 % model error, stiction), 4 gave 0.28 N while moving,
        # 10-20 about 0.23 N (following the plan); 10 keeps a factor 2 from the largest tried
        # damping ratio 0.3: over the wire the state is about a tick old when the command
        # acts, and 0.7 then rang at half the loop rate on joint 3 up to the effort ceiling.
        # In-process, 3 cm move at 500 Hz, measured joints one tick late: 0.7 and 0.5
        # aborted, 0.4 / 0.3 / 0.2 held (0.115 / 0.109 / 0.109 N); two ticks late only 0.2
        # held. On bench_cooperative's cases (1 N stiction, 15 % model error, 1 kHz) 0.2
        # aborted on the 50 kN/m string and 0.3 gave 0.142 / 0.164 N (0.7: 0.108 / 0.148).
        return ImpedanceGains(Md=None, Kp=np.full(3, 200.0), damping_ratio=0.3, Kp_across=None,
                              force_feedback=10.0), True
    raise ValueError(f"object kind must be 'spring' or 'string', got {kind!r}")


@dataclass
class Motion:
    """Master motion in the world frame: translation (m) and object rotation (rad) over
    `duration` s, starting `start` s after the controller starts."""

    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    duration: float = 5.0
    start: float = 2.0


def arm_preset(kind: str) -> ArmImpedanceGains:
    """Gains of a slave whose impedance the arm runs (servo_ci), per object.

    The arm closes the spring and damper in its own servo loop next to the motors, and the
    set-point is fed forward (force and stretch), so the spring along the object only
    has to carry what the feedforward misses: friction at the start and end of a motion,
    model error. The stiffer it is, the less of that reaches the object (K_obj / (Kp +
    K_obj)); the tension loop's gain is capped by the series stiffness, so stiffer is also
    slower to correct. Chosen on bench/bench_cooperative_arm.py (the wire's timing in sim
    time, 3 cm move, 5 N): spring 1000 N/m (400: 0.20 N at 100 Hz, 1000: 0.175 N), string
    2000 N/m (1000: 0.28 N, 2000: 0.265 N at 100 Hz; 0.18 N at 500 Hz), both damped at a
    ratio of 1 against spring + object (0.7 overshot the start-up ramp by 0.65-0.8 N on the
    string). Across the object 1000 N/m holds the slave on its path."""
    if kind == "spring":
        return ArmImpedanceGains(kp_along=1000.0, damping_ratio=1.0)
    if kind == "string":
        return ArmImpedanceGains(kp_along=2000.0, damping_ratio=1.0)
    raise ValueError(f"object kind must be 'spring' or 'string', got {kind!r}")


@dataclass
class ArmCommand:
    kind: str                       # "position", "effort" or "impedance"
    q: np.ndarray | None = None     # servo_jp position (rad, rad, m)
    dq: np.ndarray | None = None    # servo_jp velocity
    effort: np.ndarray | None = None  # servo_jf effort (N m, N m, N)
    # "impedance" (the arm's servo_ci, see rig.control.arm_impedance): the shaft end's target and
    # velocity (RCM frame), the object's direction u there, the spring and damper on the
    # axes of rig.control.arm_impedance.force_frame(u), joint feedforward (N m, N m, N)
    target: np.ndarray | None = None
    velocity: np.ndarray | None = None
    u: np.ndarray | None = None
    stiffness: np.ndarray | None = None
    damping: np.ndarray | None = None
    feedforward: np.ndarray | None = None


class CooperativeController:
    """Master in position control, slaves in impedance control with tension tracking.

    `rcm_frames`: each arm's RCM frame in the world (4x4, from the registration).
    `models`: a FeedforwardModel per slave (identified model, or nominal).
    `friction`: a StickSlipCompensation per slave.
    `elements`: the object's elements as pairs of arm names (the load cells' order).
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
        if mode not in ("impedance", "position"):
            raise ValueError(f"mode must be 'impedance' or 'position', got {mode!r}")
        if slave_control not in ("effort", "arm"):
            raise ValueError(f"slave_control must be 'effort' or 'arm', got {slave_control!r}")
        self.mode = mode
        # "effort": the slaves' impedance closed here, their efforts commanded (servo_jf);
        # "arm": the arm closes it (servo_ci), this loop moves its goal and feedforward
        self.slave_control = slave_control
        self.arm_gains = arm_gains or ArmImpedanceGains()
        self.slew_translation = slew_translation   # m/s of the user's Cartesian increments
        self.slew_rotation = slew_rotation         # rad/s of the object rotation increments
        self.slew_force = slew_force               # N/s of the tension increments
        self.position_loop = position_loop or PositionForceLoop()
        self._next_position_step = 0.0
        self.arms = list(arms)
        self.master = master
        self.slaves = [a for a in arms if a != master]
        self.dt = dt
        self.R = {a: rcm_frames[a][:3, :3].copy() for a in arms}
        self.p = {a: rcm_frames[a][:3, 3].copy() for a in arms}
        self.elements = list(elements)
        self.force = float(force)
        self.motion = motion or Motion()
        self.loop = loop or ForceLoop()
        g = gains or ImpedanceGains()
        arm = slave_control == "arm"
        self.kp_along = self.arm_gains.kp_along if arm else float(np.mean(g.Kp))
        # proportional tension feedback (dimensionless), with the arm's own inertia only;
        # none in the arm (a measured force fed back at the rate heard over the wire would
        # drive the arm-object mode)
        self.k_fp = float(g.force_feedback) if g.Md is None and not arm else 0.0
        self.kp_across = None if arm else g.Kp_across
        self.impedance = {s: Impedance(models[s], friction[s], None if g.Md is None else g.Md.copy(),
                                       g.Kp.copy(), g.Kd.copy(), g.damping_ratio,
                                       float(np.max(g.Kp)) + object_stiffness * (1.0 + self.k_fp))
                          for s in self.slaves}
        # Joint-state filter: quantised position plus the noisy velocity the dVRK reports.
        self.joint_filter = {a: KalmanDifferentiator(3, dt, [6e-6, 6e-6, 1e-6], [20.0, 20.0, 5.0],
                                                     rate_noise=[2e-3, 2e-3, 3e-4]) for a in arms}
        self.force_filter = KalmanDifferentiator(len(self.elements), dt, force_noise, 200.0)
        self.t0: float | None = None
        self.x_f = {s: 0.0 for s in self.slaves}
        self.x_g: dict[tuple[str, int], float] = {}   # slave-slave element offsets (m)
        self.tension = np.zeros(len(self.elements))
        self.tension_rate = np.zeros(len(self.elements))
        self.force_setpoint = 0.0
        self.blind = False  # the last step held the force loop (see step)
        self._t_previous: float | None = None
        self._dt_tick = dt  # s since the last step (see step)
        self._intervals_ready = False
        self._setpoint_rate = 0.0  # N/s
        # User increments (/psm/cmd_vel, /psm/cmd_force, keyboard): these are the targets;
        # the controller moves its applied offsets toward them at the slew rates, so that an
        # increment is a short ramp, not a step in one cycle.
        self.force_offset = 0.0                 # N
        self.offset_translation = np.zeros(3)   # m, world frame
        self.offset_rotation = np.zeros(3)      # rad, Euler x-y-z of the object
        self.applied_force_offset = 0.0
        self.applied_translation = np.zeros(3)
        self.applied_rotation = np.zeros(3)
        self._offset_velocity = np.zeros(3)
        # Slaves follow the master's measured motion (its PID lags its command; following
        # the command would stretch the object by that lag) rather than its set-point.
        self.follow_measured_master = follow_measured_master
        self.object_stiffness = float(object_stiffness)

    # -- frames -------------------------------------------------------------------------
    def tip_world(self, arm: str, q: np.ndarray) -> np.ndarray:
        return self.p[arm] + self.R[arm] @ K.tip_in_rcm(q)

    def to_rcm(self, arm: str, x_world: np.ndarray) -> np.ndarray:
        return self.R[arm].T @ (x_world - self.p[arm])

    # -- life cycle ---------------------------------------------------------------------
    def start(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray], tension: np.ndarray,
              stamps: dict[str, float] | None = None, tension_t: np.ndarray | None = None) -> None:
        """Start the plan at `t` from the arms at `q`, `dq` and the object at `tension`;
        `stamps`, `tension_t`: the times those samples were taken (see `step`)."""
        self.t0 = t
        self._t_previous = None
        self._dt_tick = self.dt
        for a in self.arms:
            self.joint_filter[a].reset(q[a], dq[a])
        self._filtered = {a: (np.asarray(q[a], float).copy(), np.asarray(dq[a], float).copy()) for a in self.arms}
        self._js_stamp = dict(stamps) if stamps is not None else {}
        # per arm, the smallest (this loop's time - the sample's stamp) seen: the offset of
        # the stamps' clock plus the shortest way here (see step)
        self._stamp_offset = {a: t - float(stamps[a]) for a in self.arms} if stamps is not None else {}
        if stamps is not None and not self._intervals_ready:
            # samples will come at their own intervals: their filter gains, solved before the loop
            for f in (*self.joint_filter.values(), self.force_filter):
                f.prepare_intervals()
            self._intervals_ready = True
        self.force_filter.reset(np.asarray(tension, float))
        self._force_t = None if tension_t is None else float(np.mean(tension_t))
        self.x0 = {a: self.tip_world(a, q[a]) for a in self.arms}
        self.centroid0 = np.mean([self.x0[a] for a in self.arms], axis=0)
        self.initial_tension = float(np.mean(tension)) if len(tension) else 0.0
        self.initial_element_tension = np.asarray(tension, float).copy()
        self.raw_tension = self.initial_element_tension.copy()
        # the estimate the first step starts from, even if it must hold (see step)
        self.tension = self.initial_element_tension.copy()
        self.tension_rate = np.zeros(len(self.tension))
        # the set-point ramp starts once every slave holds its object taut
        self.slack = {s: (self.mode == "impedance" and self.force > self.loop.contact
                          and self._tracked_tension(s, tension) < self.loop.contact) for s in self.slaves}
        self.ramp_start = t if not any(self.slack.values()) else None
        self.k_i = {s: self._force_gain(s, q[s]) for s in self.slaves}
        self._k_damp = self.loop.k_damp
        # x_f must be able to reach the ceiling tension through the impedance spring
        self.x_f_limit = max(self.loop.x_f_limit, 2.0 * self.force / self.kp_along + 0.01)
        if self.mode == "impedance" and self.slave_control == "effort":
            # Pre-load each slave's impedance with the tension already on the object, so that
            # switching the slave to effort control does not let the object pull it in.
            # (In the arm the set-point tension is a force feedforward: no pre-load.)
            for s in self.slaves:
                tracked = [k for k, e in enumerate(self.elements) if s in e and self.master in e]
                held = _mean_of(self.initial_element_tension, tracked)
                self.x_f[s] = held / self.kp_along

    def _position_slave(self, s: str, t: float, error: float, x_d: np.ndarray, v_d: np.ndarray,
                        u: np.ndarray) -> ArmCommand:
        """Thesis 7.7.3: fixed target steps along the object while the error is outside the deadband."""
        pl = self.position_loop
        if t + 1e-12 >= self._next_position_step:
            if abs(error) > pl.deadband and not self.blind:
                self.x_f[s] = float(np.clip(self.x_f[s] + pl.step * np.sign(error),
                                            -self.x_f_limit, self.x_f_limit))
            if s == self.slaves[-1]:
                self._next_position_step = t + pl.period
        x_rcm = self.to_rcm(s, x_d + u * self.x_f[s])
        q = K.ik_rcm(x_rcm)
        dq = np.linalg.solve(K.tip_jacobian_rcm(q), self.R[s].T @ v_d)
        return ArmCommand("position", q=q, dq=dq)

    def _arm_impedance(self, s: str, q: np.ndarray, x_t: np.ndarray, v_d: np.ndarray, a_d: np.ndarray,
                       u: np.ndarray, tips: dict[str, np.ndarray], mine: list[int], tracked: list[int],
                       hold: bool, take_up: bool = False) -> ArmCommand:
        """The slave's goal for the impedance the arm runs (servo_ci; see rig.control.arm_impedance).

        The set-point tension is a force feedforward along the object (each element it holds
        pulls the tip toward its neighbour with the set-point: the arm pushes back with
        it), so x_f only has to correct what the plan does not know; the model's
        feedforward of the planned motion (rigid body, friction, offsets) rides with it.

        `take_up`: the object is slack; the arm pushes the slave outward with the take-up
        force and no spring along the object (x_t is where it is along it), so it arrives
        at the object at that tension, below the set-point, however late the loop sees it:
        taken up by position, a stiff string overshot by K_obj x speed x the loop's delay
        (20 kN/m x 10 mm/s x 20 ms = 4 N)."""
        from rig.control.arm_impedance import cartesian_inertia, force_frame

        R = self.R[s]
        J = K.tip_jacobian_rcm(q)
        v_r, a_r, u_r = R.T @ v_d, R.T @ a_d, R.T @ u
        dq_plan = np.linalg.solve(J, v_r)
        imp = self.impedance[s]
        # friction of the planned motion only: the measured velocity reaches this loop a tick
        # or two late over the wire, and compensation on it acts after the slave has already
        # broken away or stuck (the 0.7 Hz ringing seen at 100 Hz over the wire persisted
        # either way: it is not this; see issue 35's note)
        tau = imp.model(q, dq_plan, np.linalg.solve(J, a_r)) + imp.friction(dq_plan, 0.0, dq_plan)
        # the object's stretch for the set-point is fed forward too (its configured
        # stiffness): with the force alone, the spring would take up part of every change
        # of the set-point (K_obj / (Kp + K_obj) of it reaches the object) and x_f would
        # have to integrate the rest
        held = _mean_of(self.initial_element_tension, tracked)
        target = x_t if take_up else x_t + u * ((self.force_setpoint - held) / self.object_stiffness)
        f_world = np.zeros(3)
        for k in mine:
            a, b = self.elements[k]
            other = b if a == s else a
            d = tips[s] - tips[other]
            w = d / max(np.linalg.norm(d), 1e-9)
            f_world += self.force_setpoint * w
            if k not in tracked:
                # the slave-slave element: its tension error integrated into an offset along
                # it, half by each of its slaves (as the effort path)
                self._integrate_pair(s, k, hold)
                target = target + w * (self.x_g.get((s, k), 0.0)
                                       + 0.5 * (self.force_setpoint - self.initial_element_tension[k])
                                       / self.object_stiffness)
        if take_up:
            f_world = u * max(self.loop.contact, min(self.loop.take_up_force, 0.6 * self.force))
        tau = tau + J.T @ (R.T @ f_world)
        Rf = force_frame(u_r)
        M = imp.model.mass_matrix(q)
        g = self.arm_gains
        stiffness = np.array([0.0 if take_up else g.kp_along, g.kp_across, g.kp_across])
        dirs = [R.T @ d for d in self._neighbour_directions(s, tips)]
        damping = np.empty(3)
        for i in range(3):
            axis = Rf[:, i]
            k_obj = self.object_stiffness * sum(float(axis @ d) ** 2 for d in dirs)
            damping[i] = 2.0 * g.damping_ratio * np.sqrt((stiffness[i] + k_obj) * cartesian_inertia(M, J, axis))
        return ArmCommand("impedance", target=R.T @ (target - self.p[s]), velocity=v_r, u=u_r,
                          stiffness=stiffness, damping=damping, feedforward=tau)

    def _integrate_pair(self, s: str, k: int, hold: bool) -> None:
        """Integrate the tension error of the slave-slave element k into slave s's offset
        along it (half of it: each of its two slaves takes half); none while any slave is
        slack or the force loop holds."""
        if any(self.slack.values()) or hold:
            return
        e_k = self.force_setpoint - float(self.tension[k])
        g = 0.5 * self.k_i[s] * (e_k - np.sign(e_k) * self.loop.deadband) if abs(e_k) > self.loop.deadband else 0.0
        r_k = g - 0.5 * self.loop.k_damp * float(self.tension_rate[k])
        self.x_g[(s, k)] = min(max(float(self.x_g.get((s, k), 0.0) + self._dt_tick * r_k), -self.x_f_limit),
                               self.x_f_limit)

    def _neighbour_directions(self, slave: str, tips: dict[str, np.ndarray]) -> list[np.ndarray]:
        """Unit vectors from each arm the slave shares an element with, to the slave."""
        out = []
        for a, b in self.elements:
            if slave in (a, b):
                other = b if a == slave else a
                v = tips[slave] - tips[other]
                out.append(v / max(np.linalg.norm(v), 1e-9))
        return out

    def _outward(self, slave: str, tips: dict[str, np.ndarray]) -> np.ndarray:
        """Unit vector (world) along which the slave's target moves to raise its tension:
        away from the master along their element."""
        v = tips[slave] - tips[self.master]
        return v / max(np.linalg.norm(v), 1e-9)

    def _force_gain(self, slave: str, q: np.ndarray) -> float:
        """Integral gain of the tension loop, kept a factor `bandwidth_ratio` below the slave's
        mechanical mode against the object (sqrt((Kp + K_obj) / Lambda_u)): faster than that
        and the loop drives the arm-object oscillation."""
        imp = self.impedance[slave]
        u_world = self._outward(slave, {**self.x0, slave: self.tip_world(slave, q)})
        u = self.R[slave].T @ u_world
        if self.slave_control == "arm":
            from rig.control.arm_impedance import cartesian_inertia

            Lam = cartesian_inertia(imp.model.mass_matrix(q), K.tip_jacobian_rcm(q), u) * np.eye(3)
        elif imp.Md is None:
            J = K.tip_jacobian_rcm(q)
            Lam = np.linalg.inv(J @ np.linalg.inv(imp.model.mass_matrix(q)) @ J.T)
        else:
            Lam = np.diag(imp.Md)
        kp = self.kp_along
        # the object's stiffness along u: each element contributes K (u . its direction)^2
        dirs = self._neighbour_directions(slave, {**self.x0, slave: self.tip_world(slave, q)})
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

    def desired(self, t: float, targets: bool = False
                ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
        """World-frame desired tip positions, velocities and accelerations (eq. 6.2-6.3), with
        the user offsets applied so far, or with their targets (`targets=True`: what a
        limit check of the rest of the plan needs)."""
        m = self.motion
        s = (t - self.t0 - m.start) / m.duration if m.duration > 0 else 1.0
        p, v, a = min_jerk(s)
        inside = 0.0 <= s <= 1.0
        v, a = (v / m.duration, a / m.duration**2) if inside else (0.0, 0.0)
        shift = p * m.translation + (self.offset_translation if targets else self.applied_translation)
        angles = p * m.rotation + (self.offset_rotation if targets else self.applied_rotation)
        if angles.any():
            R = euler_xyz(angles)
            # rate of the object's rotation along the planned profile: a finite difference
            eps = 1e-4
            dR = (euler_xyz(angles + eps * m.rotation) - R) / eps * v if m.rotation.any() else np.zeros((3, 3))
        else:
            R, dR = np.eye(3), np.zeros((3, 3))
        xd, vd, ad = {}, {}, {}
        rotated = angles.any()
        for arm in self.arms:
            r0 = self.x0[arm] - self.centroid0
            # without a rotation R r0 = r0 and dR r0 = 0 exactly: the products are skipped
            xd[arm] = self.centroid0 + shift + (R @ r0 if rotated else r0)
            vd[arm] = v * m.translation + (dR @ r0 if rotated else 0.0) + (0.0 if targets else self._offset_velocity)
            ad[arm] = a * m.translation
        return xd, vd, ad

    def _tracked_tension(self, slave: str, tension: np.ndarray) -> float:
        tracked = [k for k, e in enumerate(self.elements) if slave in e and self.master in e]
        return _mean_of(np.asarray(tension), tracked)

    def force_target(self, t: float) -> float:
        if self.ramp_start is None:      # still taking up slack
            return self.initial_tension + self.applied_force_offset
        ramp = self.loop.ramp_time
        if self.slave_control == "arm" and self.force > 0:
            # taken up by force, the object starts the ramp part-way up: the rest of it
            # takes its share of the ramp time (at least 0.3 s)
            ramp *= max(0.3, min(1.0, (self.force - self.initial_tension) / self.force))
        s = (t - self.ramp_start) / ramp if ramp > 0 else 1.0
        p, _, _ = min_jerk(s)
        return self.initial_tension + p * (self.force - self.initial_tension) + self.applied_force_offset

    def _slew_offsets(self) -> None:
        """Move the applied user offsets toward their targets at the slew rates."""
        if (self.applied_force_offset == self.force_offset
                and (self.applied_translation == self.offset_translation).all()
                and (self.applied_rotation == self.offset_rotation).all()):
            # nothing left to slew (the usual case): the same result as below, without its cost
            self._offset_velocity = np.zeros(3)
            return

        def toward(applied, target, rate):
            d = np.asarray(target, float) - applied
            n = float(np.linalg.norm(d))
            limit = rate * self._dt_tick
            return target if n <= limit else applied + d * (limit / n)

        before = self.applied_translation.copy()
        self.applied_translation = np.array(toward(self.applied_translation, self.offset_translation,
                                                   self.slew_translation), float)
        self._offset_velocity = (self.applied_translation - before) / self._dt_tick
        self.applied_rotation = np.array(toward(self.applied_rotation, self.offset_rotation, self.slew_rotation), float)
        self.applied_force_offset = float(toward(np.array([self.applied_force_offset]),
                                                 np.array([self.force_offset]), self.slew_force)[0])

    def step(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray],
             tension: np.ndarray | None, blind: bool = False, stamps: dict[str, float] | None = None,
             tension_t: np.ndarray | None = None) -> dict[str, ArmCommand]:
        """One control cycle. `tension`: newest sample per object element, or None if no new one.

        `blind`: the newest tension sample is too old to act on (the caller judges its age
        against the load cell's frame period). The force loop then holds: the tension
        estimate is not extrapolated, and no offset moves (x_f, x_g, the slack take-up, the
        position-mode steps); the impedance keeps the slaves where their targets were and
        the master keeps to its plan; the first sample after the hold restarts the tension
        filter. Acting on a stale tension instead winds the offsets up against a force that
        is no longer measured: samples that stopped reaching the loop for 0.3 s during the
        take-up let the spring be stretched to 9 N while the controller read 0 N, and the
        effort jumped past the ceiling when they resumed.

        `stamps` (s, per arm) and `tension_t` (s, per element): when the joint and tension
        samples were taken. Given, the filters step by the samples' own intervals (a sample
        seen again is not fed twice), and the loop's integrators by the time since the last
        step: over the wire a loop asked for 200 Hz ran at 120-160 Hz, and taken as `dt`
        apart its filters read rates 25-65 % too fast (0.36-0.91 N of error on the emulated
        wire instead of 0.18). Without them every step is `dt` after the last (a loop in
        sim time).
        """
        if self.t0 is None:
            raise RuntimeError("start() the controller first")
        t_last = self._t_previous
        elapsed = self.dt if (stamps is None or t_last is None or t <= t_last) else t - t_last
        # the integrators' step: the time since the last step, within a quarter and four
        # loop periods (a longer gap is a held process: its tension is judged by `blind`)
        self._dt_tick = self.dt if abs(elapsed - self.dt) <= 1e-6 * self.dt else min(max(elapsed, 0.25 * self.dt),
                                                                                      4.0 * self.dt)
        qf, dqf = {}, {}
        for a in self.arms:
            if stamps is None:
                qf[a], dqf[a] = self.joint_filter[a].update(q[a], dq[a])
                continue
            self._stamp_offset[a] = min(self._stamp_offset.get(a, np.inf), t - float(stamps[a]))
            last = self._js_stamp.get(a)
            if last is not None and stamps[a] <= last:
                qf[a], dqf[a] = self._filtered[a]  # the sample the last step had
                continue
            qf[a], dqf[a] = self.joint_filter[a].update(q[a], dq[a], dt=None if last is None else stamps[a] - last)
            self._js_stamp[a] = float(stamps[a])
            self._filtered[a] = (qf[a], dqf[a])
        # a hold lasts until a new sample arrives (with three cells: from every one)
        hold = bool(blind) or (self.blind and tension is None)
        if hold:
            pass  # keep the last estimate: no extrapolation over a gap of unknown length
        elif tension is not None:
            self.raw_tension = np.asarray(tension, float).copy()
            if self.blind:
                # the first sample after a hold: the filter restarts from it (the rate over
                # the gap is unknown; taken as one step's change it would kick x_f by k_damp)
                self.force_filter.reset(self.raw_tension)
                self.tension, self.tension_rate = self.raw_tension.copy(), np.zeros_like(self.raw_tension)
            else:
                dt_f = None
                if tension_t is not None and self._force_t is not None:
                    dt_f = max(float(np.mean(tension_t)) - self._force_t, 0.1 * self.dt)
                self.tension, self.tension_rate = self.force_filter.update(np.asarray(tension, float), dt=dt_f)
            if tension_t is not None:
                self._force_t = float(np.mean(tension_t))
        else:
            self.tension, self.tension_rate = self.force_filter.update(
                self.force_filter.x[:, 0], dt=None if tension_t is None and stamps is None else self._dt_tick)
            if self._force_t is not None:
                self._force_t += self._dt_tick
        self.blind = hold
        self._slew_offsets()
        xd, vd, ad = self.desired(t)
        previous, t_previous = self.force_setpoint, self._t_previous
        self.force_setpoint = self.force_target(t)
        # on the loop's own clock: a held tick is longer than dt
        self._setpoint_rate = (0.0 if t_previous is None or t <= t_previous
                               else (self.force_setpoint - previous) / (t - t_previous))
        self._t_previous = t
        tips = {a: self.tip_world(a, qf[a]) for a in self.arms}
        commands: dict[str, ArmCommand] = {}

        # Master: Cartesian position control through the inverse kinematics.
        m = self.master
        x_rcm = self.to_rcm(m, xd[m])
        q_m = K.ik_rcm(x_rcm)
        J = K.tip_jacobian_rcm(q_m)
        dq_m = np.linalg.solve(J, self.R[m].T @ vd[m])
        commands[m] = ArmCommand("position", q=q_m, dq=dq_m)

        if self.follow_measured_master:
            # The master's lag behind its plan, in position and velocity (from its joint
            # filter): slaves add it to their own plan, so that their impedance does not
            # resist the motion the object imposes (the damping along the object is hundreds
            # of N s/m: a lag changing by a millimetre per second is a newton). The lag's
            # acceleration is left out: differentiated twice, the measurement is noise.
            # The lag is taken at the time of the master's sample: against the plan of now,
            # a sample `age` s old read the plan's own motion over that age as lag, and the
            # slaves trailed the master by v x age (over the wire, rig sim's samples were
            # 7 ms old at the median and 50-100 ms at the worst, rig sim itself behind the
            # clock on a loaded machine: 20 mm/s x 50 ms is 1 mm, 0.7 N on the spring).
            Jm = K.tip_jacobian_rcm(qf[m])
            # The sample's time on this loop's clock: its stamp plus the smallest offset seen
            # (the stamps may come from another computer's clock: the console's).
            t_m = t if stamps is None else min(t, self._js_stamp[m] + self._stamp_offset[m])
            xm, vm = (xd, vd) if t_m == t else self.desired(t_m)[:2]
            shift, v_shift = tips[m] - xm[m], self.R[m] @ (Jm @ dqf[m]) - vm[m]
        for s in self.slaves:
            if self.follow_measured_master:
                xd[s] = xd[s] + shift
                vd[s] = vd[s] + v_shift
            # Which elements this slave holds, and its outward direction.
            mine = [k for k, e in enumerate(self.elements) if s in e]
            tracked = [k for k in mine if m in self.elements[k]]
            h_e = _mean_of(self.tension, tracked)
            h_rate = _mean_of(self.tension_rate, tracked)
            u = self._outward(s, tips)
            error = self.force_setpoint - h_e
            if self.mode == "position":
                commands[s] = self._position_slave(s, t, error, xd[s] + 0.0, vd[s], u)
                continue
            if hold and self.slack[s] and self.slave_control == "arm":
                # no new tension: keep taking up by force (it cannot exceed the take-up force)
                commands[s] = self._arm_impedance(s, qf[s], xd[s] + u * float(u @ (tips[s] - xd[s])),
                                                  vd[s], ad[s], u, tips, mine, tracked, hold, take_up=True)
                continue
            if hold:
                rate = 0.0
            elif self.slack[s] and self.slave_control == "arm" and not hold:
                if h_e < self.loop.contact:
                    # taken up by force (see _arm_impedance): no spring along the object
                    commands[s] = self._arm_impedance(s, qf[s], xd[s] + u * float(u @ (tips[s] - xd[s])),
                                                      vd[s], ad[s], u, tips, mine, tracked, hold, take_up=True)
                    continue
                # taut: the spring and the set-point's stretch start from here
                self.slack[s] = False
                self.x_f[s] = float(u @ (tips[s] - xd[s]))
                self.initial_element_tension = self.tension.copy()
                if not any(self.slack.values()):
                    self.ramp_start = t
                    self.initial_tension = float(np.mean([self._tracked_tension(a, self.tension)
                                                          for a in self.slaves]))
                rate = 0.0
            elif self.slack[s]:
                if h_e >= self.loop.contact:
                    self.slack[s] = False
                    if not any(self.slack.values()):
                        self.ramp_start = t
                        self.initial_tension = float(np.mean([self._tracked_tension(a, self.tension)
                                                              for a in self.slaves]))
                v_out = float(self.R[s] @ (K.tip_jacobian_rcm(qf[s]) @ dqf[s]) @ u - vd[s] @ u)
                rate = self.loop.take_up_gain * (self.loop.take_up_speed - v_out)
            else:
                # in the arm the set-point's own rise is fed forward: the damping acts on
                # the error's rate, not on the tension's (it would fight every ramp)
                damped = h_rate - (self._setpoint_rate if self.slave_control == "arm" else 0.0)
                rate = -self._k_damp * damped
                if abs(error) > self.loop.deadband:
                    rate += self.k_i[s] * (error - np.sign(error) * self.loop.deadband)
            self.x_f[s] = min(max(float(self.x_f[s] + self._dt_tick * rate), -self.x_f_limit), self.x_f_limit)
            x_t = xd[s] + u * self.x_f[s]
            if self.slave_control == "arm":
                # the set-point's stretch is motion the arm must make: its damping and friction
                # are fed forward with the plan's (x_f's rate is not: fed back through the
                # damping, the loop's own correction limit-cycled)
                v_t = vd[s] + u * (self._setpoint_rate / self.object_stiffness)
                commands[s] = self._arm_impedance(s, qf[s], x_t, v_t, ad[s], u, tips, mine, tracked, hold)
                continue
            if self.kp_across is not None:
                u_r = self.R[s].T @ u
                self.impedance[s].Kp = (self.kp_across * np.eye(3)
                                        + (self.kp_along - self.kp_across) * np.outer(u_r, u_r))
            kp_mean = self.kp_along
            for k in mine:
                if k not in tracked:
                    # The slave-slave element: its pull is fed forward (the impedance does not
                    # yield to it), and its tension error is integrated into a second offset
                    # along it, half by each of its two slaves.
                    a, b = self.elements[k]
                    other = b if a == s else a
                    d = tips[s] - tips[other]
                    w = d / max(np.linalg.norm(d), 1e-9)
                    self._integrate_pair(s, k, hold)
                    x_t = x_t + w * (self.tension[k] / kp_mean + self.x_g.get((s, k), 0.0))
            # The force the tip exerts on the object: each element's tension, pointing from
            # the neighbour to this tip (outward).
            h_world = np.zeros(3)
            for k in mine:
                a, b = self.elements[k]
                other = b if a == s else a
                d = tips[s] - tips[other]
                h_world += self.tension[k] * d / max(np.linalg.norm(d), 1e-9)
            R = self.R[s]
            f_extra = None
            if self.k_fp and tracked and not self.slack[s]:
                # on the newest raw sample: the Kalman filter's lag, not the sensor noise
                # (0.02 N times k_fp, filtered by the arm's inertia), limits this gain
                error_fb = self.force_setpoint - _mean_of(self.raw_tension, tracked)
                f_extra = R.T @ (self.k_fp * error_fb * u)
            tau = self.impedance[s](qf[s], dqf[s], R.T @ (x_t - self.p[s]), R.T @ vd[s], R.T @ ad[s], R.T @ h_world,
                                    f_extra)
            commands[s] = ArmCommand("effort", effort=tau)
        return commands
