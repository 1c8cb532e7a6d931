"""External joint torque of a PSM (joints 1-3) from its measured motion and effort: a
generalized-momentum observer on the arm's identified model (issue 47).

Why a momentum observer and not the plain residual tau_ext = M ddq + C dq + g + f - tau:
the residual needs the joint accelerations, which no recording carries (the dVRK reports
q, dq and the effort; the WPI recordings too) and which, differentiated from the noisy
velocity, carry noise that grows with the bandwidth. The observer works on the momentum
p = M(q) dq instead (De Luca and Mattone, ICRA 2003):

    p_dot = tau + tau_ext + C(q, dq)^T dq - g(q) - f(q, dq)          (M_dot = C + C^T)
    r(t)  = K_O ( p(t) - p(0) - integral_0^t (tau - f + C^T dq - g + r) ds )

so that r_dot = K_O (tau_ext - r): each joint's estimate is the external torque through a
first-order low-pass of bandwidth K_O (rad/s), decoupled per joint, with no acceleration
and no differentiation. K_O is the estimator's filter: the noise of the measured velocity
enters as K_O M dq_noise, the model's error at the frequencies below K_O as it is. A
"filtered residual" (the residual's first-order low-pass written without ddq) is the same
filter reached another way; the observer form keeps it on the momentum, which the
identified model gives exactly (M from the standard parameters, rotor inertia included).

f is everything the model file knows beside the rigid body: Coulomb (smooth sign),
viscous and offset terms, the identified Stribeck excess (`PSMDynamics.friction`) and the
file's catalogue effects that are loads (`calibration.effects.EffectCompensation`: a Dahl
state is run through the samples as the controller's feedforward runs it). A backlash and
an effort delay are not loads and are left out (named by ``skipped``). Joint 3's
stick-slip terms (`rig friction-ramp`) are not a torque the model can predict: while
joint 3 sticks its friction is anywhere in [Fs_neg, Fs_pos], so the estimate there cannot
tell a contact from friction (`calibration.tip_force` flags it and widens its spread).

Units: SI (rad, m, rad/s, m/s, N m, N, s); the external torque (N m, N m, N) is the
generalised force the environment applies: tau_ext = J^T F for a force F on the tool tip.
"""

from __future__ import annotations

import numpy as np

#: Default observer bandwidth K_O (rad/s): 3 Hz. The cooperative loop holds a tension that
#: changes over seconds, and the estimate's worst error there is a joint breaking away from
#: static friction (a transient of about 0.1 s the model cannot know): on the simulated
#: rig's 5 cm moves (bench_tension_estimate, loop on the cell, estimate vs cell while
#: moving) 8 Hz gave max 0.78 / 0.66 N (string / spring), 5 Hz 0.66 / 0.50, 3 Hz 0.58 /
#: 0.40, 2 Hz 0.52 / 0.37, the RMS 0.09-0.15 N throughout; 3 Hz keeps the lag a loop
#: closed on the estimate sees to 53 ms.
DEFAULT_GAIN = 2 * np.pi * 3.0


class MomentumObserver:
    """One arm's observer; call `update` once per sample in time order.

    ``dynamics``: `rig.model.psm_dynamics.PSMDynamics` (the identified or nominal model).
    ``effects``: a model file's ``effects`` entries (fed as loads) or None. ``gain``:
    K_O (rad/s), scalar or per joint.
    """

    def __init__(self, dynamics, effects=None, gain=DEFAULT_GAIN):
        from calibration.effects import EffectCompensation

        self.dyn = dynamics
        self.gain = np.broadcast_to(np.asarray(gain, float), (3,)).copy()
        if np.any(~(self.gain > 0)):
            raise ValueError(f"observer gain must be > 0 rad/s, got {gain}")
        self._entries = list(effects or [])
        self.effects = EffectCompensation(self._entries, dynamics.slope) if self._entries else None
        self.skipped = self.effects.skipped if self.effects is not None else []
        self.r = np.zeros(3)
        self._integral = np.zeros(3)
        self._p0: np.ndarray | None = None

    def reset(self, q=None, dq=None) -> None:
        """Start again: the next `update` (or this state, when given) is the initial momentum."""
        from calibration.effects import EffectCompensation

        self.r = np.zeros(3)
        self._integral = np.zeros(3)
        self._p0 = None
        if self._entries:
            self.effects = EffectCompensation(self._entries, self.dyn.slope)
        if q is not None:
            self._p0 = self.momentum(np.asarray(q, float), np.zeros(3) if dq is None else np.asarray(dq, float))

    def momentum(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self.dyn.mass_matrix(q) @ dq

    def known_torque(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """g(q) - C(q, dq)^T dq + f(q, dq): what the momentum's rate loses to the model's
        own forces (N m, N m, N)."""
        dyn = self.dyn
        beta = dyn.gravity_torque(q) - dyn.coriolis_matrix(q, dq).T @ dq
        f = dyn.friction(dq)
        if self.effects is not None:
            f = f + self.effects(q, dq)
        return beta + f

    def update(self, q, dq, tau, dt: float) -> np.ndarray:
        """Advance by one sample (q, dq, measured effort tau; dt s since the previous one) and
        return the external joint torque estimate r (3,)."""
        q, dq, tau = (np.asarray(x, float)[:3] for x in (q, dq, tau))
        p = self.momentum(q, dq)
        if self._p0 is None:
            self._p0 = p
            self.known_torque(q, dq)   # advances a stateful effect to this sample
            return self.r.copy()
        if not dt > 0:
            raise ValueError(f"samples must advance in time (dt = {dt} s)")
        self._integral += (tau - self.known_torque(q, dq) + self.r) * dt
        self.r = self.gain * (p - self._p0 - self._integral)
        return self.r.copy()


def observe(dynamics, effects, q, dq, tau, rate: float, gain=DEFAULT_GAIN) -> np.ndarray:
    """(n, 3) external joint torque estimates over a recording (q, dq, tau (n, 3) at ``rate``
    Hz), the observer started at rest on its first sample."""
    obs = MomentumObserver(dynamics, effects, gain)
    q, dq, tau = (np.asarray(x, float) for x in (q, dq, tau))
    out = np.empty((len(q), 3))
    dt = 1.0 / float(rate)
    for k in range(len(q)):
        out[k] = obs.update(q[k], dq[k], tau[k], dt)
    return out
