"""A small physical model of a dVRK tool's wrist and jaw (roll, wrist pitch, wrist yaw, jaw) under the dVRK's PID.

Why: `rig sim` serves a whole PSM, so joints 4-6 and the jaw must move like a tool's: lag
behind a set-point, stop at the tool's mechanical range, stick under friction when
unpowered, saturate at the motors' torque and report what a dVRK reports (quantised encoder
positions, a noisy velocity estimate, efforts from the motor currents), with the tool's
actuator-to-joint coupling where it shows. It is stepped once per 1 kHz tick per arm in a
Python loop, so it is small and fast.

Structure (per tick of h = 0.001 s; a longer step is cut into ticks of at most 1 ms):

1. Sensing, in actuator space as on the robot. The encoders sit on the motors:
   a = C^-1 q (C = the tool's ActuatorToJointPosition), quantised to one count,
   2 pi / (4000 * 11.71) = 1.34e-4 rad at the disc (ClassicPSM encoder CPT and gear ratio
   of dvrk-io-config-generator.py; the real recording shared/data/wpi-psm shows exactly
   this step times the coupling on its roll and pitch). The reported joint position is
   C a_q, so the quantum differs per joint and the wrist joints' quanta are coupled.
   Velocity: the true one plus noise added per disc and mapped by C.
2. The dVRK's PID, as at the commit in rig.model.psm_tool: it runs on the four discs
   (share/pid/sawControllersPID-PSM.json "disc_1".."disc_4": p_gain 6.0 N m/rad, d_gain
   0.09 N m s/rad, i_gain 0), the arm converting joint set-points and velocity goals by
   JointToActuatorPosition = C^-1 and efforts by JointToActuatorEffort = C^T before
   handing them over (mtsIntuitiveResearchKitArm::servo_jp_internal, servo_jf_internal,
   feed_forward_jf_internal). Per disc: effort = Kp (p_sp - p) + Kd (v_sp - v) +
   feed-forward, as in sawControllers' mtsPID (the version read, from 2020, has
   Kp e - Kd v + Ki sum(e) + offset + feed-forward, clipped to the effort limits; that the
   current one uses the velocity goal as v_sp is taken from the arm sending it). In joint
   space the PID is the coupled stiffness C^-T Kp C^-1 (off-diagonal between wrist pitch,
   wrist yaw and jaw): an error on one of them pushes the others. A joint that is not in
   position mode gets its set-point from its measurement (as mtsPID does for a joint it
   does not control), so the PID adds nothing through it.
3. Saturation: the commanded joint effort at the tool's ftmax (the dVRK only reports ftmax
   in configuration_js; the model enforces it as the tool's rating), then each disc at
   DISK_MAX_TORQUE = 0.67 A * 0.0438 N m/A * 11.71 = 0.3436 N m (the amplifiers' current
   limit). The delivered joint effort is C^-T of the disc efforts: for all eight tools of
   rig.model.psm_tool it stays within ftmax (checked over the whole box of commands), and the
   disc limit makes the roll's real maximum 0.3436 / 1.5632 = 0.22 N m, below its 0.33.
4. Mechanics per joint, integrated semi-implicitly: inertia m, viscous b, Coulomb Fc
   (implicit: a joint whose impulse is below Fc h sticks, exactly), an external effort
   (set_external_effort, e.g. an object in the jaws), and stiff damped stops (implicit
   too, so any stiffness is stable at 1 kHz). The measured effort is the motor effort
   (what the currents give: C^-T of the disc efforts, with noise per disc); it does not
   include friction or the stops, as on the robot.

What is modelled of the coupling: the PID on the discs, disc saturation, encoder
quantisation and velocity / effort noise in actuator space, the conversion of every
effort and set-point by the tool's matrix. What is not: the inertial coupling. The motors'
inertia is diagonal on the discs, so in joint space it is C^-T J_a C^-1, whose wrist
pitch / yaw terms correlate by 0.69 for the large needle driver; the model keeps its
diagonal (the inertia each joint feels with the others held, the "reflected" inertia)
because friction and the PID dominate a wrist's motion (in the real recording the inertial
torques are below the noise: a fit cannot resolve them) and because a diagonal inertia lets
friction and the stops be solved exactly joint by joint. Also not modelled: cable
stretch, the friction's dependence on the other joints, the cable-spring preload the
recording shows (0.002-0.01 N m/rad, within the PID's error), gravity on the tool (grams
at millimetres), the sterile adapter's engage procedure, the PID's tracking-error fault
(tracking_error() reports it; acting on it is the caller's), back-EMF and current loop.

Numbers (WristParams) and where they come from:

* disc inertia J_a = 1.1e-6 kg m^2 * 11.71^2 = 1.51e-4 kg m^2: the motor rotor reflected
  through the gear. The dVRK's files give Kt = 0.0438 N m/A and the 11.71 ratio but not
  the motor; 1.1e-6 kg m^2 is the rotor inertia of a 25-mm graphite-brush DC motor of that
  torque constant (an estimate; the tool's own parts, grams at millimetre radii, add
  ~1e-8). Reflected to the joints (diag of C^-T J_a C^-1), large needle driver:
  roll 6.2e-5, wrist pitch 2.8e-4, wrist yaw 2.0e-4, jaw 5.1e-5 kg m^2.
* friction per joint (Coulomb, viscous), fitted to the wrist joints of the real PSM
  recording shared/data/wpi-psm/one_results.csv (Fc tanh(dq/0.02) + Fv dq + offset,
  least squares on Savitzky-Golay derivatives of the positions; R^2 0.77-0.91; the
  recording's tool is unknown): roll 0.0025 N m, 0.0010 N m s/rad; wrist pitch 0.0060,
  0.0105; wrist yaw 0.0062, 0.0095; jaw 0.0102, 0.0094. These are 1-6 % of ftmax: the
  PID's dead band is Fc / (its joint stiffness), about 1-3 mrad.
* stops at the software limits plus 0.05 rad (the dVRK's software limits sit inside the
  tool's mechanical range; 0.05 rad is an estimate), except the jaw's lower one: the
  blades meet at 0 rad, and the dVRK's negative jaw limit (-40 deg for the large needle
  driver, "to allow stronger torque" in its tool file) squeezes them against each other.
  Stiffness 200 N m/rad (an estimate: a full ftmax of 0.33 N m presses 1.7 mrad in),
  critically damped with the joint's inertia; the stop only pushes.
* noise (scaled by `noise`, 0 for none): velocity 0.01 rad/s per disc (an estimate for the
  firmware's period-based estimator; the 2019 recording, with an older estimator, shows
  0.13-0.2 rad/s), effort 5e-4 N m per disc (the recording's high-frequency effort noise
  is 5-7e-4 N m per joint). Encoder quantisation is always on.

Behaviour that follows (tests/rig/model/test_wrist_plant.py): a step of 0.3 rad (0.5 on the
jaw) on every joint at once settles to 2 % in 60-70 ms on roll and wrist and 125 ms on
the jaw, without overshoot, and ends within the friction dead band (1-5 mrad; the PID's
own tolerance is 0.6 rad per disc); full effort presses 0.75-1.3 mrad into a stop at rest
and at most 3.7 mrad when the joint arrives at speed.

Units: rad, rad/s, N m, kg m^2, s. Vectors of 4: [roll, wrist pitch, wrist yaw, jaw].
The hot path is written on Python floats: for four joints numpy's per-call overhead costs
more than the arithmetic (a numpy version of the same tick took 38-47 us, this one 14-19 us
on the project's 2-core machine; measured() 1.7 us, setpoint() 3.4 us).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.model.psm_tool import (
    DEFAULT_TOOL,
    DISK_MAX_TORQUE,
    WRIST_ENCODER_CPT,
    WRIST_GEAR_RATIO,
    WRIST_PID_D_GAIN,
    WRIST_PID_P_GAIN,
    WRIST_PID_TOLERANCE,
    Tool,
)

JOINT_NAMES = ("outer_roll", "outer_wrist_pitch", "outer_wrist_yaw", "outer_jaw")
TICK = 0.001  # s: the longest step the PID and the mechanics take at once
ENCODER_RESOLUTION = 2.0 * math.pi / (WRIST_ENCODER_CPT * WRIST_GEAR_RATIO)  # rad at a disc
ROTOR_INERTIA = 1.1e-6  # kg m^2, estimate (module doc)
JAW_CLOSED = 0.0        # rad: the blades meet


@dataclass(frozen=True)
class WristParams:
    """Physical numbers of the wrist model (module doc says where each comes from)."""

    disc_inertia: float = ROTOR_INERTIA * WRIST_GEAR_RATIO ** 2   # kg m^2 per disc
    coulomb: tuple[float, float, float, float] = (0.0025, 0.0060, 0.0062, 0.0102)  # N m
    viscous: tuple[float, float, float, float] = (0.0010, 0.0105, 0.0095, 0.0094)  # N m s/rad
    stop_margin: float = 0.05          # rad beyond the software limits
    stop_stiffness: float = 200.0      # N m / rad
    stop_damping_ratio: float = 1.0
    velocity_noise: float = 0.01       # rad/s per disc, 1 sigma at noise = 1
    effort_noise: float = 5e-4         # N m per disc, 1 sigma at noise = 1
    disc_max_torque: float = DISK_MAX_TORQUE  # N m


def _mv(M, x):
    """4x4 (nested lists) times a 4-list."""
    x0, x1, x2, x3 = x
    return [r[0] * x0 + r[1] * x1 + r[2] * x2 + r[3] * x3 for r in M]


class WristPlant:
    """Roll, wrist pitch, wrist yaw and jaw of one tool with the dVRK's disc PID.

    Starts unpowered ("off") at q = 0. Commands: servo_jp (position mode), servo_jf (effort
    mode), hold, off; entries that are NaN leave their joint as it was, so joints can be in
    different modes. step(h) advances the plant; measured() and setpoint() read it.
    """

    joint_names = JOINT_NAMES

    def __init__(self, tool: Tool = DEFAULT_TOOL, rng: np.random.Generator | None = None,
                 noise: float = 1.0, params: WristParams | None = None):
        self.tool = tool
        self.params = p = params or WristParams()
        self.rng = rng if rng is not None else np.random.default_rng()
        self.noise = float(noise)
        C = tool.coupling_matrix
        Ci = np.linalg.inv(C)
        self.coupling = C
        Kp = np.asarray(WRIST_PID_P_GAIN, float)
        Kd = np.asarray(WRIST_PID_D_GAIN, float)
        self._C = C.tolist()
        self._Ci = Ci.tolist()
        self._CT = C.T.tolist()
        self._CiT = Ci.T.tolist()
        self._Gp = (Ci.T @ np.diag(Kp) @ Ci).tolist()   # joint-space PID stiffness
        self._Gd = (Ci.T @ np.diag(Kd) @ Ci).tolist()   # joint-space PID damping
        self.pid_tolerance = np.asarray(WRIST_PID_TOLERANCE, float)
        self.q_min = tool.q4_min
        self.q_max = tool.q4_max
        self.effort_max = tool.effort4_max
        self._ft = self.effort_max.tolist()
        self._qmin = self.q_min.tolist()
        self._qmax = self.q_max.tolist()
        # mechanics
        self.inertia = p.disc_inertia * np.diag(Ci.T @ Ci)          # reflected, kg m^2
        self.coulomb = np.asarray(p.coulomb, float)
        self.viscous = np.asarray(p.viscous, float)
        lo = self.q_min - p.stop_margin
        if tool.jaw_min < JAW_CLOSED:
            lo[3] = JAW_CLOSED
        self.stop_min = lo
        self.stop_max = self.q_max + p.stop_margin
        self.stop_damping = 2.0 * p.stop_damping_ratio * np.sqrt(p.stop_stiffness * self.inertia)
        self._m = self.inertia.tolist()
        self._lo = self.stop_min.tolist()
        self._hi = self.stop_max.tolist()
        self._k = float(p.stop_stiffness)
        self._dmax = float(p.disc_max_torque)
        self._consts: dict[float, tuple] = {}
        # noise pools (joint space), refilled from rng
        self._pool_size = 2048
        self._vn: list = []
        self._en: list = []
        self._n = self._pool_size
        # state
        self.t = 0.0
        self._q = [0.0] * 4
        self._dq = [0.0] * 4
        self._ext = [0.0] * 4
        self._mode = ["off"] * 4
        self._pos = [0.0] * 4          # 1.0 where position mode
        self._q_sp = [0.0] * 4
        self._dq_sp = [0.0] * 4
        self._ff = [0.0] * 4           # feed-forward of position joints (joint space)
        self._eff = [0.0] * 4          # user effort of effort joints (joint space)
        self._tau = [0.0] * 4          # applied motor effort (joint space)
        self._e = [0.0] * 4            # last position error of position joints
        self._sense()

    # ---------------------------------------------------------------- commands
    def servo_jp(self, q4, dq4=None, effort4=None) -> None:
        """Position mode: set-points q4 (clipped to the software limits, as the dVRK does),
        velocity set-points dq4 (default 0) and feed-forward efforts effort4 (default 0)."""
        q4 = np.asarray(q4, float)
        for i in range(4):
            x = float(q4[i])
            if math.isnan(x):
                continue
            self._mode[i] = "position"
            self._pos[i] = 1.0
            self._q_sp[i] = min(max(x, self._qmin[i]), self._qmax[i])
            self._dq_sp[i] = 0.0 if dq4 is None or math.isnan(float(dq4[i])) else float(dq4[i])
            self._ff[i] = 0.0 if effort4 is None or math.isnan(float(effort4[i])) else float(effort4[i])
            self._eff[i] = 0.0

    def servo_jf(self, tau4) -> None:
        """Effort mode: joint efforts tau4 (N m), saturated at ftmax."""
        tau4 = np.asarray(tau4, float)
        for i in range(4):
            x = float(tau4[i])
            if math.isnan(x):
                continue
            self._mode[i] = "effort"
            self._pos[i] = 0.0
            self._eff[i] = min(max(x, -self._ft[i]), self._ft[i])
            self._ff[i] = 0.0

    def hold(self, joints=None) -> None:
        """Position mode at the measured position, zero velocity (all joints or the indices given)."""
        q = self._q_meas
        for i in range(4) if joints is None else joints:
            self._mode[i] = "position"
            self._pos[i] = 1.0
            self._q_sp[i] = q[i]
            self._dq_sp[i] = 0.0
            self._ff[i] = 0.0
            self._eff[i] = 0.0

    def off(self, joints=None) -> None:
        """Unpowered: no motor effort, friction only (all joints or the indices given)."""
        for i in range(4) if joints is None else joints:
            self._mode[i] = "off"
            self._pos[i] = 0.0
            self._eff[i] = 0.0
            self._ff[i] = 0.0

    def set_external_effort(self, tau4) -> None:
        """Effort from outside on each joint (N m), e.g. an object the jaws close on; held until changed."""
        self._ext = [float(x) for x in tau4]

    def set_state(self, q, dq=None) -> None:
        """Put the wrist at q (rad) with velocities dq (default 0); set-points are left alone."""
        self._q = [float(x) for x in q]
        self._dq = [0.0] * 4 if dq is None else [float(x) for x in dq]
        self._sense()

    # ------------------------------------------------------------------- reads
    @property
    def modes(self) -> tuple[str, str, str, str]:
        return tuple(self._mode)

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """True (q, dq), without quantisation or noise."""
        return np.array(self._q), np.array(self._dq)

    def measured(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, effort) as the dVRK reports them: encoder counts through the coupling,
        the noisy velocity estimate, the motor efforts (C^-T of the disc efforts) with noise."""
        en = self._en_now
        tau = self._tau
        return (np.array(self._q_meas), np.array(self._dq_meas),
                np.array([tau[0] + en[0], tau[1] + en[1], tau[2] + en[2], tau[3] + en[3]]))

    def setpoint(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, effort) the controller works to: set-points of position joints (the
        measurement for others, as mtsPID reports), and the motor effort it commands."""
        qm, dqm = self._q_meas, self._dq_meas
        q = [self._q_sp[i] if self._pos[i] else qm[i] for i in range(4)]
        dq = [self._dq_sp[i] if self._pos[i] else dqm[i] for i in range(4)]
        return np.array(q), np.array(dq), np.array(self._tau)

    def tracking_error(self) -> np.ndarray:
        """Per disc: is the PID's position error beyond its p_measured_setpoint_tolerance?"""
        e_a = np.abs(np.array(_mv(self._Ci, self._e)))
        return e_a > self.pid_tolerance

    def energy(self) -> float:
        """Kinetic energy of the joints plus the energy stored in the stops (J)."""
        ke = 0.5 * sum(m * v * v for m, v in zip(self._m, self._dq))
        pe = 0.0
        for i in range(4):
            d = max(self._lo[i] - self._q[i], self._q[i] - self._hi[i], 0.0)
            pe += 0.5 * self._k * d * d
        return ke + pe

    # ----------------------------------------------------------------- stepping
    def step(self, h: float = TICK) -> None:
        """Advance by h seconds (ticks of at most 1 ms, the PID evaluated at each)."""
        n = max(1, math.ceil(h / TICK - 1e-9))
        dt = h / n
        c = self._consts.get(dt)
        if c is None:
            if len(self._consts) > 16:
                self._consts.clear()
            c = self._constants(dt)
        for _ in range(n):
            self._tick(dt, c)
        self.t += h

    def _constants(self, h: float) -> tuple:
        k = self._k
        free = [1.0 / (m + h * b) for m, b in zip(self._m, self.viscous.tolist())]
        hfc = (h * self.coulomb).tolist()
        contact = [1.0 / (m + h * b + h * cs + h * h * k)
                   for m, b, cs in zip(self._m, self.viscous.tolist(), self.stop_damping.tolist())]
        c = (free, hfc, contact, self.stop_damping.tolist())
        self._consts[h] = c
        return c

    def _draw(self) -> None:
        """Refill the noise pools: per-disc samples mapped to joint space."""
        s = self.noise
        n = self._pool_size
        C = self.coupling
        CiT = np.linalg.inv(C).T
        v = self.rng.standard_normal((n, 4)) * (s * self.params.velocity_noise)
        e = self.rng.standard_normal((n, 4)) * (s * self.params.effort_noise)
        self._vn = (v @ C.T).tolist()
        self._en = (e @ CiT.T).tolist()
        self._n = 0

    def _sense(self) -> None:
        """Encoder counts and velocity estimate of the present state."""
        if self._n >= self._pool_size:
            self._draw()
        vn = self._vn[self._n]
        self._en_now = self._en[self._n]
        self._n += 1
        res = ENCODER_RESOLUTION
        a = _mv(self._Ci, self._q)
        aq = [round(x / res) * res for x in a]
        self._q_meas = _mv(self._C, aq)
        dq = self._dq
        self._dq_meas = [dq[0] + vn[0], dq[1] + vn[1], dq[2] + vn[2], dq[3] + vn[3]]

    def _tick(self, h: float, c: tuple) -> None:
        free, hfc, contact, cstop = c
        pos = self._pos
        qm, dqm = self._q_meas, self._dq_meas
        # PID on the discs, written in joint space: C^-T Kp C^-1 e + C^-T Kd C^-1 ev
        e = [(self._q_sp[i] - qm[i]) * pos[i] for i in range(4)]
        ev = [(self._dq_sp[i] - dqm[i]) * pos[i] for i in range(4)]
        self._e = e
        tp = _mv(self._Gp, e)
        td = _mv(self._Gd, ev)
        ff, eff = self._ff, self._eff
        tau = [tp[i] + td[i] + ff[i] * pos[i] + eff[i] for i in range(4)]
        # the tool's rating (per joint, on the command), then the amplifiers (per disc)
        ft = self._ft
        for i in range(4):
            if tau[i] > ft[i]:
                tau[i] = ft[i]
            elif tau[i] < -ft[i]:
                tau[i] = -ft[i]
        dmax = self._dmax
        ta = [dmax if x > dmax else (-dmax if x < -dmax else x) for x in _mv(self._CT, tau)]
        tau = _mv(self._CiT, ta)
        self._tau = tau
        # mechanics, joint by joint: viscous, Coulomb and stops implicit
        q, dq, m, ext = self._q, self._dq, self._m, self._ext
        lo, hi, k = self._lo, self._hi, self._k
        qn = [0.0] * 4
        vn = [0.0] * 4
        for i in range(4):
            P = m[i] * dq[i] + h * (tau[i] + ext[i])
            f = hfc[i]
            v = (P - f) * free[i] if P > f else ((P + f) * free[i] if P < -f else 0.0)
            x = q[i] + h * v
            if x < lo[i]:
                d = lo[i] - q[i]
                P2 = P + h * k * d
                v2 = (P2 - f) * contact[i] if P2 > f else ((P2 + f) * contact[i] if P2 < -f else 0.0)
                if k * (d - h * v2) - cstop[i] * v2 > 0.0:   # the stop pushes: keep it
                    v = v2
                    x = q[i] + h * v
            elif x > hi[i]:
                d = q[i] - hi[i]
                P2 = P - h * k * d
                v2 = (P2 - f) * contact[i] if P2 > f else ((P2 + f) * contact[i] if P2 < -f else 0.0)
                if k * (d + h * v2) + cstop[i] * v2 > 0.0:
                    v = v2
                    x = q[i] + h * v
            qn[i] = x
            vn[i] = v
        self._q = qn
        self._dq = vn
        self._sense()
