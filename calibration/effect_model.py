"""What an entry of the effect catalogue (calibration.effects) is: the context its columns are
computed in, the base class every effect derives from, and the column and dynamics helpers
(the Dahl state, the crossing of a play, a delay). Units: joints 1-2 rad, rad/s, N m;
joint 3 m, m/s, N."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit


@dataclass
class EffectContext:
    """What an effect's columns may use: raw samples (n, 3) at ``rate`` Hz, the smooth-sign
    slope a (s/rad), the current model's torque prediction (n, 3) and the standard
    regressor (3n, 82) on the same samples (for payload columns)."""

    q: np.ndarray
    dq: np.ndarray
    rate: float
    slope: float
    tau_model: np.ndarray | None = None
    W_standard: np.ndarray | None = None
    body_names: tuple[str, ...] = ()
    # The current model's inertia on each joint (M_jj at the data's median configuration:
    # N m s^2/rad, kg), for the backlash crossing.
    inertia: np.ndarray | None = None
    # For the backlash crossing too: the model's M_jj on every sample (n, 3), the joint
    # accelerations the model's torque was built with (n, 3), and each joint's Coulomb level and
    # viscous coefficient in the current model (3, 2).
    mass_diag: np.ndarray | None = None
    ddq: np.ndarray | None = None
    friction: np.ndarray | None = None
    # Velocity under which each joint counts as stuck (3,).
    deadband: np.ndarray | None = None

    def sign(self, v):
        return np.tanh(0.5 * self.slope * v)


class Effect(ABC):
    """One catalogue entry (see calibration.effects): a physical component a rigid-body +
    viscous/Coulomb/offset model lacks. A subclass sets the class attributes and gives its
    `units`, `grid`, `columns`, `_params`, `sanity` and `joint_torque`; a catalogue entry is
    one instance of it."""

    id: str = ""
    description: str = ""
    variable: str = ""                  # what the residual depends on, for the attribution
    regime: str = ""                    # where it acts
    linear_names: tuple[str, ...] = ()
    grid_name: str | None = None
    uses_model: bool = False            # built from the current model's torque or regressor
    all_joints: bool = False            # payload: columns on every joint's rows
    in_rigid_body_model: bool = False   # absorbed by a model identified on the same data
    equivalent_to: tuple[str, ...] = ()
    #: Dimension of the non-linear parameter (1 for a grid value; 3 for a payload's centre).
    nonlinear_dim: int = 1
    #: The non-linear parameter is a point mass's centre, found by variable projection over
    #: the body's ten standard columns (``columns(ctx, j, None)``) instead of a grid.
    point_mass: bool = False
    #: A second, discrete non-linear parameter (a method joint -> its values); the grid value
    #: is then the pair (grid value, option) and the grid is searched for each option.
    options: Callable | None = None
    option_name: str | None = None
    #: The torque needs the joint accelerations and the model's M_jj on the samples
    #: (``torque(..., ddq=, mass_diag=)``; defaults: central differences of dq, the inertia
    #: in the parameters).
    needs_dynamics: bool = False
    #: The linear parameters' names for a grid value (a method), where their number depends
    #: on it (the option sets it); default ``linear_names``.
    names: Callable | None = None
    #: The options are nested: option o's columns are the first ones of the largest option's
    #: (a friction profile's harmonics), so the largest option's columns serve them all.
    nested_options: bool = False

    @abstractmethod
    def units(self, joint: int) -> dict:
        """{param: unit} on joint (1-3)."""

    def grid(self, joint: int) -> tuple:
        """The grid of the non-linear parameter on joint (1-3), or (None,)."""
        return (None,)

    def linear_names_at(self, g) -> tuple[str, ...]:
        """Names of the linear parameters (the columns) at grid value ``g``."""
        return tuple(self.names(g)) if self.names is not None else self.linear_names

    def n_params(self, g=None) -> int:
        """Free parameters for the information criterion at grid value ``g`` (linear + the
        non-linear ones)."""
        return len(self.linear_names_at(g)) + (self.nonlinear_dim if self.grid_name else 0)

    @abstractmethod
    def columns(self, ctx: EffectContext, joint: int, g) -> np.ndarray:
        """(n, 3, k): torque on every joint per unit of each linear parameter, on the raw samples."""

    def params(self, theta, g, joint: int, baseline: dict) -> dict:
        """Named parameters from the linear ``theta`` and grid value ``g``; ``baseline``
        carries the joint's identified Fc (for levels like Fs = Fc + dFs)."""
        return self._params(np.asarray(theta, float), g, joint, baseline)

    @abstractmethod
    def _params(self, theta: np.ndarray, g, joint: int, baseline: dict) -> dict:
        """`params` of a subclass: the named parameters of its linear ``theta``."""

    def sanity(self, params: dict, joint: int) -> str | None:
        """None when physically plausible, else the reason it is not."""
        return None

    @abstractmethod
    def joint_torque(self, p: dict, j: int, q, dq, tau_model, rate: float, slope: float, ddq=None,
                     mass_diag=None) -> np.ndarray:
        """(n,) on joint j (or (n, 3) for an effect on every joint) on raw samples (n, 3)."""

    def torque(self, params: dict, joint: int, q, dq, tau_model=None, rate: float = 200.0,
               slope: float = 400.0, ddq=None, mass_diag=None) -> np.ndarray:
        """(n, 3) torque the effect adds (N m, N) on raw samples (n, 3)."""
        q, dq = np.atleast_2d(q), np.atleast_2d(dq)
        out = np.zeros_like(q, dtype=float)
        if self.needs_dynamics:
            ddq = np.gradient(dq, 1.0 / rate, axis=0) if ddq is None else np.atleast_2d(ddq)
        res = self.joint_torque(params, joint, q, dq, tau_model, rate, slope, ddq, mass_diag)
        if self.all_joints:
            return res
        out[:, joint - 1] = res
        return out

    def step_torque(self, params: dict, joint: int, q: np.ndarray, dq: np.ndarray, step: np.ndarray,
                    state: float, slope: float) -> tuple[np.ndarray, float]:
        """One control step (calibration.effects.EffectCompensation): the (3,) torques at the
        state (q, dq), and the effect's own state (0.0 for an effect without one) advanced
        by the position change ``step`` since the previous step."""
        return self.torque(params, joint, q[None], dq[None], slope=slope)[0], state


# ----------------------------------------------------------------------------- helpers
def _u(joint: int, rot: str, lin: str) -> str:
    return lin if joint == 3 else rot


def _on(joint: int, col: np.ndarray) -> np.ndarray:
    """(n, 3, 1) with ``col`` on the joint's rows."""
    out = np.zeros((col.shape[0], 3, 1))
    out[:, joint - 1, 0] = col
    return out


def _on_k(joint: int, cols: list) -> np.ndarray:
    return np.concatenate([_on(joint, c) for c in cols], axis=2)


def _sig(dq, slope):
    return np.tanh(0.5 * slope * dq)


def dahl_state(q: np.ndarray, travel: float) -> np.ndarray:
    """Unit Dahl friction state along a joint's path q (n,): z -> sign(dq) exponentially with
    the travel since the last reversal, travel constant ``travel`` (rad or m). Exact for
    motion that is monotone between samples: the sim's own update composed over a sample."""
    dx = np.diff(q, prepend=q[0])
    z = np.empty_like(q, dtype=float)
    zk = 0.0
    for k, d in enumerate(dx):
        zk = dahl_step(zk, d, travel)
        z[k] = zk
    return z


def dahl_step(z: float, d: float, travel: float) -> float:
    """The unit Dahl state ``z`` after a move ``d`` (rad or m; monotone) of a joint with
    travel constant ``travel``: z -> sign(d) exponentially with |d| / travel."""
    if d == 0.0:
        return z
    s = 1.0 if d > 0 else -1.0
    return s + (z - s) * np.exp(-abs(d) / travel)


@njit(cache=True)
def _gap_kernel(u, inertia, vp, h, half, fc, fv, slope):
    n = u.shape[0]
    w = np.zeros(n)
    momentum = np.zeros(n)
    side = np.sign(u[0]) if n else 0.0
    x = side * half          # motor minus joint, relative to the middle of the play
    v = 0.0                  # motor minus joint velocity
    in_gap = False
    for k in range(n):
        s = np.sign(u[k])
        if not in_gap:
            if s != 0 and side != 0 and s != side:
                in_gap, v = True, 0.0
            elif side == 0:
                side = s
                x = side * half
        if in_gap:
            # The joint side, at vp - v, carries its own friction; the path's torque u was
            # computed with the friction at vp.
            rel = u[k] - fv * v - fc * (np.tanh(0.5 * slope * vp[k]) - np.tanh(0.5 * slope * (vp[k] - v)))
            v += h * rel / inertia[k]
            x += h * v
            if abs(x) >= half and v * x > 0.0:    # at a face and moving into it
                x = np.sign(x) * half
                side = np.sign(x)
                momentum[k] = inertia[k] * v
                in_gap, v = False, 0.0
                if s != side:     # the torque turned back while crossing: cross again
                    in_gap = True
            w[k] = 1.0 if in_gap or abs(x) < half else 0.0
    return w, momentum


def gap_crossings(transmitted, link_inertia, rate: float, width: float, dq=None,
                  friction=(0.0, 0.0), slope: float = 400.0):
    """Crossings of a play of total width ``width`` (rad or m), on samples at ``rate`` Hz:
    (window, momentum), each (n,). ``window`` is 1 while the play is open, else 0;
    ``momentum`` (N m s, N s) is, on the sample where the motor meets the other face, the
    joint side's momentum relative to the motor side at that contact, else 0.

    The encoder reads the motor side, which follows the measured path; the joint side is in
    contact with one face of the play while the torque the drive transmits to it
    (``transmitted``: the path's torque less the motor side's own inertia torque) pushes on it.
    When that torque changes sign the joint side is left to its own loads and the motor
    crosses the play: relative to the joint it accelerates by the transmitted torque over the
    joint side's inertia ``link_inertia`` (scalar or per sample), less the difference of the
    joint's friction (``friction`` = (Fc, Fv) with the smooth sign of ``slope``) between the
    path's velocity ``dq`` and the joint side's own, until it has travelled the width and
    meets the other face. A reversal in the middle of a crossing turns back from where the
    motor is.
    """
    u = np.ascontiguousarray(transmitted, dtype=float)
    inertia = np.ascontiguousarray(np.broadcast_to(np.asarray(link_inertia, float), u.shape))
    vp = np.zeros(len(u)) if dq is None else np.ascontiguousarray(dq, dtype=float)
    return _gap_kernel(u, inertia, vp, 1.0 / rate, 0.5 * width, float(friction[0]), float(friction[1]),
                       float(slope))


#: Time constant (s) over which the measured effort returns a contact's momentum after a
#: crossing: the position loop catching the joint side up with the path. The workflow does
#: not know the loop. Its shape is not negligible even at the 10 Hz analysis bandwidth: on
#: the nine backlash cases of bench_discrepancy (3 seeds, workflow as of 2026-11) 5 ms left
#: 7 of them and 40 ms 8 of them further from the noise floor than 20 ms (e.g. 3.8 x floor
#: at 20 ms, 4.1 at 5 ms, 8.0 at 40 ms on the pitch axis, seed 2).
GAP_RETURN = 0.02


def bridge_stuck(u: np.ndarray, dq, stuck_velocity: float) -> np.ndarray:
    """``u`` with the samples where the joint is stuck (|dq| < ``stuck_velocity``) replaced by
    the straight line between the moving samples on either side. While a joint sticks at a
    reversal its drive torque ramps through the static friction band as the position loop
    winds up; a model's torque there follows its smooth sign of a velocity near zero, which
    jumps by twice the Coulomb level at a time the ramp does not."""
    if dq is None or not stuck_velocity > 0:
        return u
    moving = np.abs(np.asarray(dq, float)) >= stuck_velocity
    if moving.all() or not moving.any():
        return u
    k = np.arange(len(u))
    return np.where(moving, u, np.interp(k, k[moving], u[moving]))


def gap_torque(tau_model, ddq, mass_diag, dq, rate: float, width: float, motor_inertia: float,
               friction=(0.0, 0.0), slope: float = 400.0, stuck_velocity: float = 0.0) -> np.ndarray:
    """(n,) change of a joint's measured effort a play of total width ``width`` makes, per
    unit unloaded fraction. The motor side (inertia ``motor_inertia``) follows the path; the
    drive transmits ``tau_model - motor_inertia * ddq`` to the joint side, whose inertia is
    ``mass_diag - motor_inertia`` (``mass_diag``: the model's M_jj, scalar or per sample).
    While the play is open (`gap_crossings`) the effort loses the transmitted torque; at each
    contact it gives back the momentum the joint side then has relative to the path, spread
    over `GAP_RETURN` (unit area). Where the joint is stuck (|dq| < ``stuck_velocity``) the
    transmitted torque is bridged (`bridge_stuck`)."""
    u = bridge_stuck(np.asarray(tau_model, float), dq, stuck_velocity) - motor_inertia * np.asarray(ddq, float)
    link = np.maximum(np.asarray(mass_diag, float) - motor_inertia, 1e-9)
    w, momentum = gap_crossings(u, link, rate, width, dq, friction, slope)
    out = -w * u
    a = np.exp(-1.0 / (rate * GAP_RETURN))
    tail = int(np.ceil(8.0 * GAP_RETURN * rate))
    kernel = (1.0 - a) * a ** np.arange(tail) * rate
    for i in np.flatnonzero(momentum):
        m = min(tail, len(u) - i)
        out[i:i + m] += momentum[i] * kernel[:m]
    return out


def delayed(x: np.ndarray, samples: float) -> np.ndarray:
    """x(t - samples / rate) by linear interpolation; the first values held."""
    n = len(x)
    idx = np.arange(n) - samples
    return np.interp(idx, np.arange(n), x)


def _geom(lo, hi, n):
    return tuple(float(v) for v in np.geomspace(lo, hi, n))


# ----------------------------------------------------------------------------- the catalogue
