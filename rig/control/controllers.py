"""Controllers of thesis chapter 7, and the filters they read through.

Feedforward linearisation, impedance and robust stick-slip friction compensation.

All controllers work in joint space for joints 1-3 and in the arm's RCM frame for
Cartesian quantities (m, N); the cooperative layer converts world-frame targets.

* `KalmanDifferentiator`: position (or force) -> filtered value and rate. A constant-
  acceleration Kalman filter designed with filterpy; because the model and noise are
  constant the gain converges, and the loop runs the converged (steady-state) gain (the
  Riccati equation's solution), which is what keeps a controller step inside the 1 ms budget. `delay()` reports its lag.
* `StickSlipCompensation`: eq. 4.16 friction with velocity deadbands and, on joint 3, the
  robust stick-slip term with a position deadband (thesis 7.5.1).
* `FeedforwardModel`: M^(q) y + N^(q, dq) + tau_f^ (eq. 7.1-7.2) from a PSMDynamics.
* `Impedance` (7.3, eq. 7.6-7.9).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from filterpy.common import Q_discrete_white_noise

from rig.model import psm_kinematics as K
from rig.model.psm_dynamics import PSMDynamics


def _transition(dt: float) -> np.ndarray:
    """The constant-acceleration model's state transition over `dt` s."""
    return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


class KalmanDifferentiator:
    """Steady-state constant-acceleration Kalman filter for n independent channels.

    Each channel's state is (value, rate, rate of rate). It measures the value and, when
    `rate_noise` is given, the rate too (the dVRK reports both a quantised position and a
    noisy velocity). `process_noise` is the std of the white jerk; it sets the trade-off
    between lag and noise. The gain is filterpy's converged one, solved for directly.

    Samples `dt` apart by default; `update(..., dt=)` takes one that came another interval
    after the last (over the wire a 200 Hz loop reads a 500 Hz stream 4 or 6 ms apart, and
    a held process later still): the prediction spans that interval and the gain is the
    steady-state one of samples that far apart (solved once per interval, to a tenth of
    `dt`); a sample more than LONGEST intervals after the last restarts the filter. Taken as `dt` apart, samples 6.4 ms apart read 28 % too fast a rate, and the
    cooperative loop that damps on it went from 0.18 to 0.36 N of error on the emulated wire.
    """

    def __init__(self, n: int, dt: float, value_noise, process_noise, rate_noise=None):
        self.n = n
        self.dt = dt
        self.F = _transition(dt)
        r = np.broadcast_to(np.asarray(value_noise, float), (n,))
        qn = np.broadcast_to(np.asarray(process_noise, float), (n,))
        rv = None if rate_noise is None else np.broadcast_to(np.asarray(rate_noise, float), (n,))
        self._noise = (r, qn, rv)
        self.m = 1 if rv is None else 2
        self.H = np.eye(3)[: self.m]
        self.gains = self._gains(dt)
        self._forms: dict[int, tuple] = {}
        # the per-step forms: F transposed for row states, each measurement's gain column
        self._Ft = self.F.T.copy()
        self._g0 = self.gains[:, :, 0].copy()
        self._g1 = self.gains[:, :, 1].copy() if self.m == 2 else None
        self.x = np.zeros((n, 3))
        self.initialised = False

    def _gains(self, dt: float) -> np.ndarray:
        r, qn, rv = self._noise
        return np.stack([self._converged_gain(r[i], qn[i], None if rv is None else rv[i], dt)
                         for i in range(self.n)])

    #: intervals (in tenths of the nominal one) whose gains `prepare_intervals` solves ahead;
    #: others are solved when first met (2-3 ms), up to LONGEST
    INTERVALS = (5, 40)
    #: nominal intervals beyond which a sample restarts the filter (`reset`): the state is
    #: too old to predict from. A gain solved for a shorter interval is no substitute: with
    #: the prediction over 5-20 intervals it made the filter unstable (spectral radius
    #: 1.5-21), and a 60 ms gap in rig sim's stream grew the slaves' bias to 115 N in 0.3 s
    LONGEST = 20.0

    def prepare_intervals(self) -> None:
        """Solve the gains of every interval in INTERVALS now (2-3 ms each), so that a
        loop meeting a usual interval does not stall on it."""
        for k in range(self.INTERVALS[0], self.INTERVALS[1] + 1):
            self._gain_form(k)

    def _gain_form(self, k: int) -> tuple:
        form = self._forms.get(k)
        if form is None:
            g = self._gains(k * self.dt / 10.0)
            form = (g[:, :, 0].copy(), g[:, :, 1].copy() if self.m == 2 else None)
            self._forms[k] = form
        return form

    def _form(self, dt: float) -> tuple:
        """(F^T, value gains, rate gains) for samples `dt` apart: the prediction over `dt`
        exactly, the steady-state gain of the interval nearest it in tenths of the nominal
        one (at least a tenth)."""
        k = max(int(round(10.0 * dt / self.dt)), 1)
        g0, g1 = self._gain_form(k)
        return _transition(dt).T, g0, g1

    def _converged_gain(self, r: float, q: float, rv: float | None, dt: float | None = None) -> np.ndarray:
        """The steady-state gain of filterpy's predict-update cycle for this channel: the
        a-priori covariance P solves the discrete algebraic Riccati equation (scipy), and
        K = P H^T (H P H^T + R)^-1 is the gain filterpy's `update` converges to. Iterating
        filterpy to convergence gives the same gain (tests/rig/control/test_control.py) but took
        38 s for the joint filter at 200 Hz, whose gain creeps to its limit."""
        dt = self.dt if dt is None else dt
        R = np.diag([max(r, 1e-12) ** 2] + ([] if rv is None else [max(rv, 1e-12) ** 2]))
        Q = Q_discrete_white_noise(dim=3, dt=dt, var=max(q, 1e-12) ** 2)
        H = self.H
        try:
            P = scipy.linalg.solve_discrete_are(_transition(dt).T, H.T, Q, R)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise ValueError(f"no steady-state Kalman gain for value noise {r}, process noise {q}"
                             f"{'' if rv is None else f', rate noise {rv}'}: {exc}") from None
        return P @ H.T @ np.linalg.inv(H @ P @ H.T + R)

    def reset(self, value: np.ndarray, rate: np.ndarray | None = None) -> None:
        self.x[:] = 0.0
        self.x[:, 0] = value
        if rate is not None:
            self.x[:, 1] = rate
        self.initialised = True

    def update(self, value: np.ndarray, rate: np.ndarray | None = None,
               dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Feed one sample per channel, `dt` s after the last (default: the nominal
        interval); returns (filtered value, rate)."""
        if not self.initialised or (dt is not None and dt > self.LONGEST * self.dt):
            self.reset(value, rate)
            return self.x[:, 0].copy(), self.x[:, 1].copy()
        if dt is None or abs(dt - self.dt) <= 1e-6 * self.dt:
            Ft, g0, g1 = self._Ft, self._g0, self._g1
        else:
            Ft, g0, g1 = self._form(dt)
        x = self.x
        # Predict in place: a caller may pass a view of x[:, 0] as `value` to coast on the
        # prediction alone (zero innovation), as the cooperative force filter does between
        # load-cell samples.
        x[:] = x @ Ft
        if self.m == 1:
            x += g0 * (value - x[:, 0])[:, None]
        else:
            x += g0 * (value - x[:, 0])[:, None] + g1 * (rate - x[:, 1])[:, None]
        return x[:, 0].copy(), x[:, 1].copy()

    def frequency_response(self, frequency: float, channel: int = 0) -> np.ndarray:
        """Complex gains from the true signal to the estimated (value, rate) at `frequency` Hz,
        the rate normalised by j w so that 1 means no error."""
        w = 2 * np.pi * frequency
        z = np.exp(1j * w * self.dt)
        Kg = self.gains[channel]
        A = self.F - Kg @ self.H @ self.F
        # a true sine s(t) gives measurements (s, j w s) in the value and rate channels
        meas = np.array([1.0, 1j * w])[: self.m]
        X = np.linalg.solve(np.eye(3) - A / z, Kg @ meas)
        return np.array([X[0], X[1] / (1j * w)])

    def delay(self, frequency: float = 2.0, channel: int = 0) -> tuple[float, float]:
        """Lag (s) of the filtered value and of the rate estimate for a sine of `frequency` Hz."""
        w = 2 * np.pi * frequency
        value, rate = self.frequency_response(frequency, channel)
        return float(-np.angle(value) / w), float(-np.angle(rate) / w)

    def noise_gain(self, channel: int = 0, samples: int = 20000, seed: int = 0,
                   value_noise: float = 1.0, rate_noise: float = 0.0) -> tuple[float, float]:
        """Std of the (value, rate) estimates when the input is pure noise of the given stds."""
        rng = np.random.default_rng(seed)
        x = np.zeros(3)
        Kg = self.gains[channel]
        out = np.empty((samples, 2))
        for k in range(samples):
            x = self.F @ x
            z = np.array([rng.normal(0, value_noise), rng.normal(0, rate_noise)])[: self.m]
            x = x + Kg @ (z - self.H @ x)
            out[k] = x[:2]
        return tuple(out[samples // 10:].std(axis=0))


@dataclass
class StickSlipCompensation:
    """Friction compensation of thesis 7.5.1.

    Joints 1-2 (and joint 3 when moving): Fc tanh(a x / 2) + Fv x + Fo with x = 0 inside the
    velocity deadband (with hysteresis: a moving joint stays moving down to half of it).
    Joint 3 at rest: +Fs_pos or Fs_neg once the position error leaves the position deadband
    (the joint is about to be pushed out of stiction), held until the error comes back
    through zero, else 0. The object keeps this state: one per arm.

    `dq_ref` (optional): the velocity the controller is about to command (its reference).
    A joint at rest whose reference moves gets the friction of the reference velocity: the
    controller then pushes it out of static friction as the motion starts instead of after
    the lag the deadband would cost (friction feedforward). Without it, thesis 7.5.1 as is.
    """

    Fc: np.ndarray
    Fv: np.ndarray
    Fo: np.ndarray
    slope: float = 400.0
    Fs_pos: float = 1.0
    Fs_neg: float = -1.0
    velocity_deadband: np.ndarray = field(default_factory=lambda: np.array([0.01, 0.01, 0.005]))
    position_deadband: float = 0.0003
    scale: float = 1.0   # fraction of the model friction to compensate (robustness margin)
    reference_deadband: float = 0.01   # fraction of the velocity deadband a reference must exceed
    _held: int = field(default=0, repr=False)   # sign of the breakaway force being applied
    _moving: np.ndarray = field(default_factory=lambda: np.zeros(3, bool), repr=False)

    def __call__(self, dq: np.ndarray, position_error3: float, dq_ref: np.ndarray | None = None) -> np.ndarray:
        # A joint counts as moving once |dq| leaves the deadband and until it falls below half
        # of it: a joint sliding at about the deadband speed would otherwise flick the
        # compensation on and off with the velocity noise.
        speed = np.abs(dq)
        self._moving = np.where(self._moving, speed >= 0.5 * self.velocity_deadband, speed >= self.velocity_deadband)
        x = np.where(self._moving, dq, 0.0)
        if dq_ref is not None:
            # a planned motion sets the friction's direction and size: smooth, noise-free
            x = np.where(np.abs(dq_ref) >= self.reference_deadband * self.velocity_deadband, dq_ref, x)
        f = self.scale * (self.Fc * np.tanh(0.5 * self.slope * x) + self.Fv * x) + self.Fo
        if not self._moving[2] and x[2] == 0.0:
            # Schmitt trigger: the breakaway force goes on when the error leaves the deadband
            # and stays on until the error has come back through zero (or the joint moves),
            # so sensor noise at the deadband's edge cannot make it chatter.
            e = position_error3
            if e > self.position_deadband:
                self._held = 1
            elif e < -self.position_deadband:
                self._held = -1
            elif self._held * e <= 0.0:
                self._held = 0
            f[2] = self.Fo[2] + (self.Fs_pos if self._held > 0 else self.Fs_neg if self._held < 0 else 0.0)
        else:
            self._held = 0
        return f


class FeedforwardModel:
    """u = M^(q) y + N^(q, dq) (eq. 7.1-7.2), from an identified or nominal PSMDynamics.

    ``effects`` (optional): a callable (q, dq) -> (3,) torques of the effects a model file
    adds to the rigid body (`calibration.effects.EffectCompensation`, built by the
    procedure from the file), fed forward with N^. It may keep state (a Dahl friction
    state): one per arm, called once per control step."""

    def __init__(self, dynamics: PSMDynamics, effects=None):
        self.dyn = dynamics
        self.effects = effects

    def __call__(self, q: np.ndarray, dq: np.ndarray, y: np.ndarray) -> np.ndarray:
        # One RNEA pass gives M y + C dq + g (friction added separately).
        u = self.dyn.inverse_dynamics(q, dq, y, friction=False)
        if self.effects is not None:
            u = u + self.effects(q, dq)
        return u

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        return self.dyn.mass_matrix(q)


@dataclass
class Impedance:
    """Cartesian impedance of the tool tip (thesis 7.3, eq. 7.6-7.9), position only.

    Closed loop: Md (xdd_d - xdd) + Kd (xd_d - xd) + Kp (x_d - x) = h_e, with h_e the
    force the tip exerts on the environment (N, RCM frame). Kp, Kd are diagonal (N/m,
    N s/m). For position the analytic and geometric Jacobians coincide (T_A = I).

    `Md` is the desired inertia (kg, diagonal). With `Md=None` the desired inertia is the
    arm's own Cartesian inertia Lambda^(q) = J^-T M^ J^-1: then the measured-force terms of
    eq. 7.6 and 7.7 cancel exactly and the loop needs no force measurement, which keeps it
    stable against stiff objects (a string at 20 kN/m), where feeding back a filtered,
    sampled force with a desired inertia other than the arm's own limit-cycles. The
    thesis' choice (Md = M^ at home) aims at the same cancellation.
    """

    model: FeedforwardModel
    friction: StickSlipCompensation
    Md: np.ndarray | None = None
    Kp: np.ndarray = field(default_factory=lambda: np.array([15.0, 15.0, 15.0]))
    Kd: np.ndarray = field(default_factory=lambda: np.array([3.0, 3.0, 3.0]))
    # With the arm's own inertia, damping can instead be set as a ratio against a design
    # stiffness (N/m; the impedance plus the object's): D = 2 zeta Lambda^1/2 sqrt(K). The
    # Cartesian inertia of a PSM is strongly anisotropic (rotor inertia seen through a
    # ~0.1 m lever is tens of kg across the tool, under 1 kg along it), so one diagonal Kd
    # cannot damp every direction well.
    damping_ratio: float | None = None
    design_stiffness: float = 0.0

    def _stiffness(self, e: np.ndarray) -> np.ndarray:
        """Kp e, with Kp diagonal (a vector) or a full symmetric 3x3 matrix (N/m)."""
        return self.Kp @ e if np.ndim(self.Kp) == 2 else self.Kp * e

    def __call__(self, q: np.ndarray, dq: np.ndarray, x_d: np.ndarray, xd_d: np.ndarray,
                 xdd_d: np.ndarray, h_e: np.ndarray, f_extra: np.ndarray | None = None) -> np.ndarray:
        """Joint efforts for the target (x_d, its velocity and acceleration; RCM frame) and the
        measured force h_e the tip exerts. `f_extra` (N, RCM frame): a force the caller adds
        to the spring and damper (an outer force loop's term)."""
        # J, and J-dot q-dot by a directional difference of the closed-form Jacobian (exact
        # to O(eps^2)), in one vectorised evaluation.
        eps = 1e-6
        Js = K.tip_jacobian_rcm(np.stack([q, q + eps * dq, q - eps * dq]))
        J = Js[0]
        # One inverse serves the three solves with J and the Cartesian inertia below: a 3x3
        # inverse costs what one solve does, and both fail alike only where J is singular
        # (the tip at the RCM).
        Jinv = np.linalg.inv(J)
        Jdot_dq = (Js[1] - Js[2]) @ dq / (2 * eps)
        x = K.tip_in_rcm(q)
        xd = J @ dq
        if self.Md is not None and self.damping_ratio is not None:
            D = np.diag(2.0 * self.damping_ratio * np.sqrt(self.Md * self.design_stiffness))
            spring = self._stiffness(x_d - x) + D @ (xd_d - xd)
        elif self.Md is None and self.damping_ratio is not None:
            Lam = Jinv.T @ self.model.mass_matrix(q) @ Jinv
            w, V = np.linalg.eigh(Lam)
            Lam_half = (V * np.sqrt(np.maximum(w, 0.0))) @ V.T
            D = 2.0 * self.damping_ratio * np.sqrt(self.design_stiffness) * Lam_half
            spring = self._stiffness(x_d - x) + D @ (xd_d - xd)
        else:
            spring = self._stiffness(x_d - x) + self.Kd * (xd_d - xd)
        if f_extra is not None:
            spring = spring + f_extra
        # Stiction (7.5.1) acts on the error to where the impedance would come to rest, the
        # target displaced by the measured force (x_d - Kp^-1 h_e): in contact the target
        # itself is never reached, and its error would hold the breakaway force on for good
        # and flip it as the geometry changes. Joint 3 puts the tip at distance
        # q3 - L_RCC + L_TOOL from the RCM.
        rest = x_d - (np.linalg.solve(self.Kp, h_e) if np.ndim(self.Kp) == 2 else h_e / self.Kp)
        q_target3 = float(np.sqrt(rest @ rest)) + K.L_RCC - K.L_TOOL
        fric = self.friction(dq, q_target3 - q[2], Jinv @ xd_d)
        if self.Md is None:
            y = Jinv @ (xdd_d - Jdot_dq)
            return self.model(q, dq, y) + fric + J.T @ spring
        a = xdd_d + (spring - h_e) / self.Md
        y = Jinv @ (a - Jdot_dq)
        return self.model(q, dq, y) + fric + J.T @ h_e


def follow_path(plant, dynamics: PSMDynamics, effects=None, seconds: float = 3.0, record: float = 2.0,
                q0=(0.1, -0.1, 0.12), seed: int = 1) -> float:
    """RMS tip error (m) over the last ``record`` s of one simulated arm following a Lissajous
    path (2 x 2 x 1.5 cm at 0.5 Hz, the third axis at twice that) from its tip at ``q0``
    under `Impedance` (300 N/m, damping ratio 0.8, the arm's own inertia) with the model
    ``dynamics`` (its eq. 4.16 friction compensated) and ``effects`` fed forward
    (`FeedforwardModel`). ``plant`` = (PSMParameters, HiddenEffects) of the simulated arm.
    A bench of what a model is worth to a controller on a given plant."""
    from rig.sim.world import ArmSpec, SimWorld

    params, plant_effects = plant
    q0 = np.asarray(q0, float)
    w = SimWorld([ArmSpec("A", params=params, effects=plant_effects, q0=q0)], seed=seed)
    w.set_state("A", q0)
    d = dynamics.params.drive
    imp = Impedance(FeedforwardModel(dynamics, effects),
                    StickSlipCompensation(d.Fc.copy(), d.Fv.copy(), d.Fo.copy(), d.slope), None,
                    np.full(3, 300.0), np.zeros(3), damping_ratio=0.8, design_stiffness=300.0)
    x0, a, wv = K.tip_in_rcm(q0), np.array([0.02, 0.02, 0.015]), np.pi
    n = int(round(seconds / w.dt))
    first = n - int(round(record / w.dt))
    errors = []
    for k in range(n):
        t = k * w.dt
        s, c, s2, c2 = np.sin(wv * t), np.cos(wv * t), np.sin(2 * wv * t), np.cos(2 * wv * t)
        xd = x0 + a * np.array([s, 1 - c, s2 / 2])
        q, dq, _ = w.measured_js("A")
        w.servo_jf("A", imp(q, dq, xd, a * wv * np.array([c, s, c2]), a * wv ** 2 * np.array([-s, c, -2 * s2]),
                            np.zeros(3)))
        w.step()
        if k >= first:
            errors.append(K.tip_in_rcm(w.true_state("A")[0]) - xd)
    return float(np.sqrt((np.array(errors) ** 2).sum(1).mean()))
