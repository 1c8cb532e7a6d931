"""The force at a PSM's tool tip from its external joint torque (issue 47), with its
uncertainty and the samples where it cannot be told from the model's own error.

tau_ext = J(q)^T F with J the 3 x 3 Jacobian of the tip position (the project's PSM
kinematics, `rig.model.psm_kinematics.tip_jacobian_rcm`, turned into the arm's base frame 0
by the RCM frame), so F = J^-T tau_ext. The external torque comes from
`calibration.momentum_observer` (its gain is the estimate's filter).

Uncertainty: the model's error on motion it never saw, per joint (the held-out RMS of
measured minus predicted effort, ``sigma``: N m, N m, N), taken as independent joint
errors: Sigma_F = J^-T diag(sigma^2) J^-1. Its square roots on the diagonal are the spread
per base axis; `spread_along(u)` is the spread of the force along a direction (a tension).

Flags (per sample), where a contact force and the model's error look alike:

* ``joint3_static``: joint 3 slower than its deadband (0.005 m/s, thesis 7.5.1). Its
  friction is then anywhere within the static band ([Fs_neg, Fs_pos] of `rig friction-ramp`,
  else +-(Fc + Fst) of the model), which the model's smooth sign cannot know. Joints 1-2
  stick too (under 0.01 rad/s); every stuck joint's spread is widened by its band, so that
  where arms are combined (`calibration.tension_estimate`) a stuck arm counts less.
* ``at_limit``: a joint within ``limit_margin`` of its range (rad, rad, m): the stop's
  force is a contact on the joint the model does not have.
* ``singular``: the Jacobian's condition number above ``max_condition`` (the tip at the
  RCM or the shaft horizontal): a small joint error is a large force.

Units: SI (m, N, N m, rad); forces in the arm's base frame 0 unless a rotation is given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.model import psm_kinematics as K

#: Velocity under which joint 3 may stick (m/s): thesis 7.5.1's deadband.
JOINT3_STATIC = 0.005
#: Velocities under which joints 1-3 may stick (rad/s, rad/s, m/s): thesis 7.5.1's deadbands.
STATIC = np.array([0.01, 0.01, JOINT3_STATIC])
#: Spread (N m, N m, N) of a model without held-out figures (the nominal one), on a moving
#: joint: its effort's noise on the simulated rig. Only the static bands come on top.
SIGMA_FLOOR = np.array([0.005, 0.005, 0.01])
#: Joints this close to a limit (rad, rad, m) are flagged.
LIMIT_MARGIN = np.array([0.02, 0.02, 0.002])
#: Jacobian condition number above which the force is flagged.
MAX_CONDITION = 200.0
#: Flag names, in the order of the ``flags`` columns.
FLAGS = ("joint3_static", "at_limit", "singular")


def base_jacobian(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) Jacobian of the tip position in the arm's base frame 0 (m/rad, 1)."""
    return K.RCM_FRAME[:3, :3] @ K.tip_jacobian_rcm(np.asarray(q, float))


def tip_force(q: np.ndarray, tau_ext: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) force on the tip (N) in frame 0, or ``rotation`` @ it (e.g. the RCM frame's
    rotation in the world), from external joint torques (..., 3)."""
    J = base_jacobian(q)
    F = np.linalg.solve(np.swapaxes(J, -1, -2), np.asarray(tau_ext, float)[..., None])[..., 0]
    return F if rotation is None else F @ np.asarray(rotation, float).T


def static_band(dynamics, stick=None) -> np.ndarray:
    """Half-width per joint (N m, N m, N) of the static friction band: the model's Coulomb
    level plus its Stribeck excess; joint 3's friction-ramp breakaway levels when known."""
    band = np.abs(np.asarray(dynamics.Fc, float)) + np.abs(np.asarray(dynamics.Fst, float))
    if stick is not None:
        band[2] = float(max(abs(stick.fs_pos), abs(stick.fs_neg)))
    return band


@dataclass
class ForceSample:
    """One tip force estimate: ``force`` (3,) N, its covariance (3, 3) N^2 (stuck joints
    widened by their static band), the flags (dict name -> bool), the external joint torque
    it came from (3,) and ``base_covariance``, the covariance from the model's error on
    moving joints alone (what arms are weighted by when combined: it does not jump as a
    joint crosses its deadband); None for a model without held-out figures)."""

    force: np.ndarray
    covariance: np.ndarray
    flags: dict
    tau_ext: np.ndarray
    base_covariance: np.ndarray | None = None

    def spread_along(self, u: np.ndarray) -> float:
        u = np.asarray(u, float)
        return float(np.sqrt(max(u @ self.covariance @ u, 0.0)))

    @property
    def ambiguous(self) -> bool:
        return any(self.flags.values())


class TipForceEstimator:
    """One arm's tip force from its measured joints and efforts: the momentum observer on
    the identified model (effects included), J^-T, the held-out spread and the flags.

    ``sigma``: the model's held-out RMS error per joint (N m, N m, N) or None (a model
    without held-out figures: `SIGMA_FLOOR`). ``stick``: joint 3's stick-slip terms (`StickSlip`) or None.
    ``rotation``: frame the forces are given in (3 x 3 from frame 0; default frame 0).
    """

    def __init__(self, dynamics, effects=None, gain=None, sigma=None, stick=None, rotation=None,
                 limit_margin=LIMIT_MARGIN, max_condition: float = MAX_CONDITION):
        from calibration.momentum_observer import DEFAULT_GAIN, MomentumObserver

        self.observer = MomentumObserver(dynamics, effects, DEFAULT_GAIN if gain is None else gain)
        self.sigma = None if sigma is None else np.asarray(sigma, float)
        self.band = static_band(dynamics, stick)
        # the spread of a moving joint: the held-out error, else the floor (a nominal model)
        self.base_sigma = SIGMA_FLOOR.copy() if self.sigma is None else self.sigma
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, float)
        self.limit_margin = np.asarray(limit_margin, float)
        self.max_condition = float(max_condition)

    def reset(self) -> None:
        self.observer.reset()

    def update(self, q, dq, tau, dt: float) -> ForceSample:
        q, dq = np.asarray(q, float)[:3], np.asarray(dq, float)[:3]
        r = self.observer.update(q, dq, tau, dt)
        return self.sample(q, dq, r)

    def sample(self, q: np.ndarray, dq: np.ndarray, r: np.ndarray) -> ForceSample:
        J = self.rotation @ base_jacobian(q)
        JT_inv = np.linalg.inv(J.T)
        force = JT_inv @ r
        flags = {"joint3_static": bool(abs(dq[2]) < JOINT3_STATIC),
                 "at_limit": bool(np.any((q - K.Q_MIN < self.limit_margin) | (K.Q_MAX - q < self.limit_margin))),
                 "singular": bool(np.linalg.cond(J) > self.max_condition)}
        # a stuck joint's friction is anywhere in its static band: its spread widens by the band
        s = np.where(np.abs(dq) < STATIC, np.hypot(self.base_sigma, self.band), self.base_sigma)
        cov = JT_inv @ np.diag(s ** 2) @ JT_inv.T
        base = None if self.sigma is None else JT_inv @ np.diag(self.sigma ** 2) @ JT_inv.T
        return ForceSample(force, cov, flags, r, base)


def heldout_sigma(model) -> tuple[np.ndarray | None, str]:
    """The model file's RMS effort error per joint on motion left out of its fit (N m, N m,
    N) and where it comes from: a `rig discrepancy` model's held-out block (the written
    model), a `rig identify` model's validation (SDP). (None, why) for a file without one."""
    v = model.validation or {}
    if v.get("heldout_rms_written") is not None:
        return np.asarray(v["heldout_rms_written"], float), "rig discrepancy's held-out block (written model)"
    rms = v.get("rms")
    if isinstance(rms, dict) and rms.get("sdp") is not None:
        return np.asarray(rms["sdp"], float), f"rig identify's validation ({v.get('source', 'held-out motion')}, SDP)"
    return None, "the model file has no held-out figures (a nominal or hand-written model)"


@dataclass
class RecordingForces:
    """Tip forces over a recording: ``force`` (n, 3) N in frame 0, ``sigma`` (n, 3) the
    spread per axis (N), ``flags`` (n, len(FLAGS)) bool, ``tau_ext`` (n, 3)."""

    t: np.ndarray
    force: np.ndarray
    sigma: np.ndarray
    flags: np.ndarray
    tau_ext: np.ndarray


def estimate_recording(dynamics, effects, q, dq, tau, rate: float, gain=None, sigma=None,
                       stick=None) -> RecordingForces:
    """The tip force over a recording (q, dq, tau (n, 3+) at ``rate`` Hz; joints 1-3 used)."""
    q, dq, tau = (np.asarray(x, float)[:, :3] for x in (q, dq, tau))
    est = TipForceEstimator(dynamics, effects, gain, sigma, stick)
    n = len(q)
    force, spread, flags, r = np.empty((n, 3)), np.empty((n, 3)), np.zeros((n, len(FLAGS)), bool), np.empty((n, 3))
    dt = 1.0 / float(rate)
    for k in range(n):
        s = est.update(q[k], dq[k], tau[k], dt)
        force[k], r[k] = s.force, s.tau_ext
        spread[k] = np.sqrt(np.clip(np.diag(s.covariance), 0.0, None))
        flags[k] = [s.flags[f] for f in FLAGS]
    return RecordingForces(np.arange(n) / float(rate), force, spread, flags, r)
