"""The effect catalogue of the discrepancy workflow (issue 7): fixed, versioned, named physics.

Each :class:`Effect` is one physical component a rigid-body + viscous/Coulomb/offset model
(thesis eq. 4.16) lacks. It gives, for one joint j (1-3):

* its regressor columns, torque = columns @ theta, linear in theta. Components that are
  non-linear in one parameter (Stribeck velocity, period of a position ripple, Dahl travel
  constant, backlash width, delay, exponent of the damping law) carry a small grid over
  that parameter; the workflow fits theta linearly inside each grid value and keeps the
  best (a profile likelihood). The grid value counts as one more parameter in the BIC.
  Backlash has a second, discrete one (the motor side's share of the joint inertia), and
  position-dependent friction its number of harmonics (the columns then number twice
  that), each searched as options with the grid; the option is chosen by the BIC;
* its parameters with units (``params``), from theta and the grid value;
* a sanity check on those parameters (e.g. Fs >= Fc >= 0): a fit that needs unphysical
  values is not that effect, whatever its score;
* the torque it adds, ``torque(params, q, dq, tau_model, rate)`` (n, 3), so the augmented
  model can be evaluated by controllers and by the simulated rig.

Columns are computed on the raw samples (``EffectContext.q``, ``dq`` at ``rate``; for those
marked ``uses_model`` also the current model's torque and regressor on the raw samples) and
the workflow filters them with the same masked zero-phase low-pass as the measured torques
(parallel filtering: a linear-in-parameters model stays exact through a linear filter).

Units: joints 1-2 rad, rad/s, N m; joint 3 m, m/s, N. ``sigma(dq)`` is the model's smooth
sign tanh(a dq / 2) with the baseline slope a.

Observational equivalences (said, not hidden): while a joint moves, a direction-dependent
Coulomb level (Fc+ for dq > 0, Fc- for dq < 0) equals a symmetric level plus a constant
(Fc+ - Fc-)/2, so ``coulomb_asymmetry`` and ``torque_offset`` explain the same data; and a
model identified on the same data already has both in its offset Fo and a payload in its
tool parameters. The workflow reports such effects as absorbed or equivalent instead of
picking one by chance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

#: 1.1: backlash returns the momentum at the contact and has a motor-side inertia (params changed).
#: 1.2: position_friction's level is a Fourier series of 1-4 harmonics of its period (params
#: a_sin, a_cos, harmonics added; 1.1 entries, one ripple as amplitude and phase, still evaluate).
#: 1.3: coulomb_asymmetry's levels follow its torque dFc (1 + sigma(dq)) / 2: Fc_pos = Fc + dFc
#: moving up, Fc_neg = Fc moving down (1.2 wrote Fc -/+ dFc/2; dFc, what is evaluated, unchanged).
CATALOGUE_VERSION = "1.3"

#: Bodies a payload is attributed to for joint 1, 2, 3 (rig.model.psm_dynamics.BODY_NAMES).
PAYLOAD_BODIES = ("yaw_link", "pitch_end", "tool")


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


@dataclass(frozen=True)
class Effect:
    """One catalogue entry (see the module docstring)."""

    id: str
    description: str
    variable: str                       # what the residual depends on, for the attribution
    regime: str                         # where it acts
    linear_names: tuple[str, ...]
    units: Callable[[int], dict]        # joint (1-3) -> {param: unit}
    grid: Callable[[int], tuple]        # joint -> grid of the non-linear parameter (or (None,))
    grid_name: str | None
    _columns: Callable                  # (ctx, joint, g) -> (n, 3, k) columns on the raw samples
    _params: Callable                   # (theta, g, joint, baseline) -> dict
    _sanity: Callable                   # (params, joint) -> str | None (None: passes)
    _torque: Callable                   # (params, joint, q, dq, tau_model, rate, slope) -> (n,) on the joint
    uses_model: bool = False            # built from the current model's torque or regressor
    all_joints: bool = False            # payload: columns on every joint's rows
    in_rigid_body_model: bool = False   # absorbed by a model identified on the same data
    equivalent_to: tuple[str, ...] = ()
    #: Dimension of the non-linear parameter (1 for a grid value; 3 for a payload's centre).
    nonlinear_dim: int = 1
    #: The non-linear parameter is a point mass's centre, found by variable projection over
    #: the body's ten standard columns (``columns(ctx, j, None)``) instead of a grid.
    point_mass: bool = False
    #: A second, discrete non-linear parameter (joint -> its values); the grid value is then
    #: the pair (grid value, option) and the grid is searched for each option.
    options: Callable | None = None
    option_name: str | None = None
    #: The torque needs the joint accelerations and the model's M_jj on the samples
    #: (``torque(..., ddq=, mass_diag=)``; defaults: central differences of dq, the inertia
    #: in the parameters).
    needs_dynamics: bool = False
    #: The linear parameters' names for a grid value, where their number depends on it (the
    #: option sets it); default ``linear_names``.
    names: Callable | None = None
    #: The options are nested: option o's columns are the first ones of the largest option's
    #: (a friction profile's harmonics), so the largest option's columns serve them all.
    nested_options: bool = False

    def linear_names_at(self, g) -> tuple[str, ...]:
        """Names of the linear parameters (the columns) at grid value ``g``."""
        return tuple(self.names(g)) if self.names is not None else self.linear_names

    def n_params(self, g=None) -> int:
        """Free parameters for the information criterion at grid value ``g`` (linear + the
        non-linear ones)."""
        return len(self.linear_names_at(g)) + (self.nonlinear_dim if self.grid_name else 0)

    def columns(self, ctx: EffectContext, joint: int, g) -> np.ndarray:
        """(n, 3, k): torque on every joint per unit of each linear parameter."""
        return self._columns(ctx, joint, g)

    def params(self, theta, g, joint: int, baseline: dict) -> dict:
        """Named parameters from the linear ``theta`` and grid value ``g``; ``baseline``
        carries the joint's identified Fc (for levels like Fs = Fc + dFs)."""
        return self._params(np.asarray(theta, float), g, joint, baseline)

    def sanity(self, params: dict, joint: int) -> str | None:
        """None when physically plausible, else the reason it is not."""
        return self._sanity(params, joint)

    def torque(self, params: dict, joint: int, q, dq, tau_model=None, rate: float = 200.0,
               slope: float = 400.0, ddq=None, mass_diag=None) -> np.ndarray:
        """(n, 3) torque the effect adds (N m, N) on raw samples (n, 3)."""
        q, dq = np.atleast_2d(q), np.atleast_2d(dq)
        out = np.zeros_like(q, dtype=float)
        if self.needs_dynamics:
            ddq = np.gradient(dq, 1.0 / rate, axis=0) if ddq is None else np.atleast_2d(ddq)
            res = self._torque(params, joint, q, dq, tau_model, rate, slope, ddq, mass_diag)
        else:
            res = self._torque(params, joint, q, dq, tau_model, rate, slope)
        if self.all_joints:
            return res
        out[:, joint - 1] = res
        return out


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
def _stiction() -> Effect:
    def cols(ctx, j, vs):
        v = ctx.dq[:, j - 1]
        return _on(j, ctx.sign(v) * np.exp(-(v / vs) ** 2))

    def params(th, vs, j, base):
        fc = base.get("Fc", 0.0)
        return {"dFs": float(th[0]), "Fs": float(fc + th[0]), "Fc": float(fc), "vs": float(vs)}

    def sanity(p, j):
        if not p["Fs"] >= p["Fc"] >= 0.0:
            return f"needs Fs >= Fc >= 0, got Fs {p['Fs']:.4g}, Fc {p['Fc']:.4g}"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        v = dq[:, j - 1]
        return p["dFs"] * _sig(v, slope) * np.exp(-(v / p["vs"]) ** 2)

    return Effect("stiction", "Stribeck / breakaway friction above Coulomb near zero velocity: "
                  "(Fs - Fc) exp(-(dq/vs)^2) sigma(dq)", "dq", "|dq| < 2 vs", ("dFs",),
                  lambda j: {"dFs": _u(j, "N m", "N"), "Fs": _u(j, "N m", "N"), "Fc": _u(j, "N m", "N"),
                             "vs": _u(j, "rad/s", "m/s")},
                  lambda j: _geom(0.002, 0.1, 7) if j < 3 else _geom(0.0004, 0.02, 7), "vs",
                  cols, params, sanity, torque)


def _coulomb_asymmetry() -> Effect:
    def cols(ctx, j, g):
        return _on(j, 0.5 * (1.0 + ctx.sign(ctx.dq[:, j - 1])))

    def params(th, g, j, base):
        fc = base.get("Fc", 0.0)
        # The torque d (1 + sigma) / 2: the level moving up is raised by d, the one moving
        # down is the baseline's.
        return {"dFc": float(th[0]), "Fc_pos": float(fc + th[0]), "Fc_neg": float(fc)}

    def sanity(p, j):
        if min(p["Fc_pos"], p["Fc_neg"]) < 0:
            return f"a Coulomb level would be negative (Fc+ {p['Fc_pos']:.4g}, Fc- {p['Fc_neg']:.4g})"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        return p["dFc"] * 0.5 * (1.0 + _sig(dq[:, j - 1], slope))

    return Effect("coulomb_asymmetry", "direction-dependent Coulomb level: Fc+ for dq > 0, Fc- for dq < 0",
                  "sign(dq)", "dq > 0 vs dq < 0", ("dFc",),
                  lambda j: {k: _u(j, "N m", "N") for k in ("dFc", "Fc_pos", "Fc_neg")},
                  lambda j: (None,), None, cols, params, sanity, torque,
                  in_rigid_body_model=True, equivalent_to=("torque_offset",))


#: Harmonics tried for a position-dependent friction level: its profile over a period P is a
#: Fourier series of this many terms (1: a single ripple; more: a smooth level varying along
#: the stroke, as the thesis found on the real insertion axis, 5.6). The information criterion
#: chooses the number with the period.
FRICTION_HARMONICS = (1, 2, 3, 4)


def _harmonics(q, period: float, n: int) -> list:
    x = 2 * np.pi * np.asarray(q, float) / period
    out = []
    for k in range(1, int(n) + 1):
        out += [np.sin(k * x), np.cos(k * x)]
    return out


def friction_profile(params: dict, q) -> np.ndarray:
    """The position-dependent part of a joint's Coulomb level, f(q) (N m, N), of a
    ``position_friction`` entry: sum over harmonics k of a_sin[k] sin(2 pi k q / P) +
    a_cos[k] cos(2 pi k q / P). Entries written before catalogue 1.2 carry a single ripple as
    amplitude and phase: A sin(2 pi q / P + phi)."""
    q = np.asarray(q, float)
    if "a_sin" not in params:
        return params["amplitude"] * np.sin(2 * np.pi * q / params["period"] + params["phase"])
    terms = _harmonics(q, params["period"], len(params["a_sin"]))
    coef = np.ravel(np.column_stack([params["a_sin"], params["a_cos"]]))
    return sum(c * t for c, t in zip(coef, terms))


def _position_friction() -> Effect:
    def cols(ctx, j, g):
        period, n = g
        s = ctx.sign(ctx.dq[:, j - 1])
        return _on_k(j, [s * t for t in _harmonics(ctx.q[:, j - 1], period, n)])

    def params(th, g, j, base):
        period, n = g
        a_sin, a_cos = th[0::2], th[1::2]
        fc = base.get("Fc", 0.0)
        f = friction_profile({"period": period, "a_sin": a_sin, "a_cos": a_cos}, np.linspace(0.0, period, 721))
        amp = float(np.max(np.abs(f)))
        return {"amplitude": amp, "phase": float(np.arctan2(a_cos[0], a_sin[0])), "period": float(period),
                "harmonics": int(n), "a_sin": [float(v) for v in a_sin], "a_cos": [float(v) for v in a_cos],
                "lowest": float(np.min(f)), "Fc": float(fc), "relative_amplitude": amp / fc if fc > 0 else float("inf")}

    def sanity(p, j):
        # The friction level Fc + f(q) must stay >= 0 (within a 20 % allowance).
        if -p["lowest"] > 1.2 * max(p["Fc"], 0.0):
            return (f"the friction level dips {-p['lowest']:.4g} below the Coulomb level {p['Fc']:.4g} "
                    "(it would turn negative)")
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        return _sig(dq[:, j - 1], slope) * friction_profile(p, q[:, j - 1])

    def names(g):
        return tuple(n for k in range(1, int(g[1]) + 1) for n in (f"a_sin{k}", f"a_cos{k}"))

    return Effect("position_friction", "Coulomb level varying with position: sigma(dq) f(q), f a Fourier "
                  "series of period P (sum over k <= K of a_k sin(2 pi k q / P) + b_k cos(2 pi k q / P))",
                  "q (in motion)", "whole stroke", ("a_sin1", "a_cos1"),
                  lambda j: {"amplitude": _u(j, "N m", "N"), "phase": "rad", "period": _u(j, "rad", "m"),
                             "harmonics": "1", "a_sin": _u(j, "N m", "N"), "a_cos": _u(j, "N m", "N"),
                             "lowest": _u(j, "N m", "N"), "Fc": _u(j, "N m", "N"), "relative_amplitude": "1"},
                  lambda j: _geom(0.15, 2.0, 9) if j < 3 else _geom(0.015, 0.2, 9), "period",
                  cols, params, sanity, torque, options=lambda j: FRICTION_HARMONICS, option_name="harmonics",
                  names=names, nested_options=True)


def _spring() -> Effect:
    def cols(ctx, j, g):
        q = ctx.q[:, j - 1]
        return _on_k(j, [q, np.ones_like(q)])

    def params(th, g, j, base):
        k = float(th[0])
        if th[1] == 0.0:
            # The constant part k q0 is not separable from the model's offset Fo here.
            return {"k": k, "q0": None}
        return {"k": k, "q0": float(-th[1] / k) if k != 0 else float("nan")}

    def sanity(p, j):
        if not p["k"] > 0:
            return f"stiffness {p['k']:.4g} is not positive (not a restoring spring)"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        return p["k"] * (q[:, j - 1] - (p["q0"] or 0.0))

    return Effect("spring", "torque proportional to position: k (q - q0) (cables, a balancing spring)",
                  "q", "whole stroke", ("k", "c0"),
                  lambda j: {"k": _u(j, "N m/rad", "N/m"), "q0": _u(j, "rad", "m")},
                  lambda j: (None,), None, cols, params, sanity, torque)


def point_mass_parameters(com) -> np.ndarray:
    """(10,) standard parameters of a unit point mass at ``com`` (m, body frame): mass 1, first
    moments c and the inertia about the frame origin |c|^2 I - c c^T, in the regressor's order
    (m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz)."""
    c = np.asarray(com, float)
    Io = (c @ c) * np.eye(3) - np.outer(c, c)
    return np.array([1.0, c[0], c[1], c[2], Io[0, 0], Io[0, 1], Io[1, 1], Io[0, 2], Io[1, 2], Io[2, 2]])


def _payload() -> Effect:
    def cols(ctx, j, com):
        b = ctx.body_names.index(PAYLOAD_BODIES[j - 1])
        W = ctx.W_standard[:, 10 * b:10 * b + 10].reshape(-1, 3, 10)  # the body's ten columns
        if com is None:
            return W
        # A point mass at com: its gravity (first moments) and its inertia, per kg.
        return (W @ point_mass_parameters(com))[:, :, None]

    def params(th, com, j, base):
        m = float(th[0])
        c = [float(x) for x in com]
        return {"mass": m, "com": c, "first_moment": [m * x for x in c], "body": PAYLOAD_BODIES[j - 1]}

    def sanity(p, j):
        if not p["mass"] > 0:
            return f"mass {p['mass']:.4g} kg is not positive"
        if not np.all(np.abs(p["com"]) < COM_BOX):
            return f"centre of mass {np.round(p['com'], 3).tolist()} m lies outside the arm"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        # A payload is a change of the rigid-body parameters, not an added torque term.
        raise ValueError("a payload changes the rigid-body parameters: use payload_standard_delta")

    return Effect("payload", "unmodelled point mass m at c on the link of the joint (default the tool): "
                  "its gravity and its inertia m (|c|^2 I - c c^T)", "q (gravity), ddq", "whole workspace",
                  ("m",), lambda j: {"mass": "kg", "com": "m (body joint frame)", "first_moment": "kg m",
                                     "body": ""},
                  lambda j: (None,), "com", cols, params, sanity, torque,
                  uses_model=True, all_joints=True, in_rigid_body_model=True, nonlinear_dim=3, point_mass=True)


#: A payload's centre must lie within this box (m, each axis of the body frame).
COM_BOX = 0.6


def payload_standard_delta(params: dict, body_names) -> np.ndarray:
    """Change of the 82 standard parameters for a point-mass payload: its mass, first moments
    and its own rotational inertia about the frame origin."""
    b = list(body_names).index(params["body"])
    d = np.zeros(10 * len(body_names) + 12)
    d[10 * b:10 * b + 10] = params["mass"] * point_mass_parameters(params["com"])
    return d


#: Motor side of a play: fractions of the joint's inertia (M_jj at the median configuration)
#: tried for the inertia on the motor side of the play (the rotor's share, which the drive
#: still has to accelerate while the play is open).
MOTOR_FRACTIONS = (0.0, 0.1, 0.2, 0.3)


def _backlash() -> Effect:
    def cols(ctx, j, g):
        width, frac = g
        inertia = float(ctx.inertia[j - 1])
        if not inertia > 0:
            return _on(j, np.zeros(len(ctx.q)))
        fc, fv = ctx.friction[j - 1]
        return _on(j, gap_torque(ctx.tau_model[:, j - 1], ctx.ddq[:, j - 1], ctx.mass_diag[:, j - 1],
                                 ctx.dq[:, j - 1], ctx.rate, width, frac * inertia, (fc, fv), ctx.slope,
                                 float(ctx.deadband[j - 1])))

    def params(th, g, j, base):
        width, frac = g
        return {"width": float(width), "unloaded_fraction": float(th[0]), "motor_fraction": float(frac),
                "motor_inertia": float(frac * base["inertia"]), "inertia": float(base["inertia"]),
                "Fc": float(base.get("Fc", 0.0)), "Fv": float(base.get("Fv", 0.0)),
                "stuck_velocity": float(base.get("stuck_velocity", 0.0))}

    def sanity(p, j):
        if not 0.2 <= p["unloaded_fraction"] <= 1.5:
            return (f"the load seen while crossing the gap drops by {p['unloaded_fraction']:.3g} of the "
                    "transmitted torque (a gap unloads by about 1)")
        if not p["inertia"] > 0:
            return f"the model's inertia on the joint is {p['inertia']:.3g}: the crossing is undefined"
        return None

    def torque(p, j, q, dq, tm, rate, slope, ddq, mass_diag):
        md = p["inertia"] if mass_diag is None else np.atleast_2d(mass_diag)[:, j - 1]
        return p["unloaded_fraction"] * gap_torque(tm[:, j - 1], ddq[:, j - 1], md, dq[:, j - 1], rate,
                                                   p["width"], p["motor_inertia"], (p["Fc"], p["Fv"]), slope,
                                                   p.get("stuck_velocity", 0.0))

    return Effect("backlash", "dead zone at torque reversal: while the motor crosses the play of width b "
                  "(driven relative to the joint side by the transmitted torque over the joint side's "
                  "inertia) the drive transmits nothing, and the contact at the far face returns the "
                  "joint side's lag in momentum", "motor travel across the play after a torque reversal",
                  "crossing the play after each reversal of the transmitted torque", ("unloaded_fraction",),
                  lambda j: {"width": _u(j, "rad", "m"), "unloaded_fraction": "1", "motor_fraction": "1",
                             "motor_inertia": _u(j, "N m s^2/rad", "kg"), "inertia": _u(j, "N m s^2/rad", "kg"),
                             "Fc": _u(j, "N m", "N"), "Fv": _u(j, "N m s/rad", "N s/m"),
                             "stuck_velocity": _u(j, "rad/s", "m/s")},
                  lambda j: _geom(0.002, 0.04, 7) if j < 3 else _geom(0.0003, 0.006, 7), "width",
                  cols, params, sanity, torque, uses_model=True, nonlinear_dim=2,
                  options=lambda j: MOTOR_FRACTIONS, option_name="motor_fraction", needs_dynamics=True)


def _hysteresis() -> Effect:
    def cols(ctx, j, travel):
        return _on(j, dahl_state(ctx.q[:, j - 1], travel))

    def params(th, travel, j, base):
        fd = float(th[0])
        return {"Fd": fd, "travel": float(travel), "sigma0": fd / travel if travel > 0 else float("nan")}

    def sanity(p, j):
        if not p["Fd"] > 0:
            return f"Dahl level {p['Fd']:.4g} is not positive"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        return p["Fd"] * dahl_state(q[:, j - 1], p["travel"])

    return Effect("hysteresis", "Dahl pre-sliding friction: a state z -> Fd sign(dq) over a travel "
                  "Fd / sigma0 after each reversal", "q travel after a velocity reversal",
                  "first few travel constants after each reversal", ("Fd",),
                  lambda j: {"Fd": _u(j, "N m", "N"), "travel": _u(j, "rad", "m"),
                             "sigma0": _u(j, "N m/rad", "N/m")},
                  lambda j: _geom(0.0005, 0.03, 8) if j < 3 else _geom(0.0001, 0.006, 8), "travel",
                  cols, params, sanity, torque)


#: Delays (s) tried for ``time_delay``.
DELAY_GRID = (0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06)


def _time_delay() -> Effect:
    def cols(ctx, j, delay):
        x = ctx.tau_model[:, j - 1]
        return _on(j, delayed(x, delay * ctx.rate) - x)

    def params(th, delay, j, base):
        return {"delay": float(delay * th[0]), "grid_delay": float(delay), "gain": float(th[0])}

    def sanity(p, j):
        # To first order tau(t - d) - tau(t) = -d dtau/dt, so the gain and the grid delay trade
        # off (and the baseline refit takes up part of a delay): what is physical is that the
        # effort lags (d = gain x grid delay > 0) by no more than the catalogue's longest delay.
        if not 0.0 < p["delay"] <= DELAY_GRID[-1]:
            return (f"the implied delay {p['delay']:.3g} s is not a lag within (0, {DELAY_GRID[-1]:g}] s "
                    f"(gain {p['gain']:.3g} at {p['grid_delay']:g} s)")
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        x = tm[:, j - 1]
        return delayed(x, p["delay"] * rate) - x

    return Effect("time_delay", "measured effort lagging the motion by d: tau(t - d)",
                  "lag of the model torque", "fast torque changes", ("gain",),
                  lambda j: {"delay": "s", "grid_delay": "s", "gain": "1"},
                  lambda j: DELAY_GRID, "delay",
                  cols, params, sanity, torque, uses_model=True)


def _torque_offset() -> Effect:
    def cols(ctx, j, g):
        return _on(j, np.ones(ctx.q.shape[0]))

    def params(th, g, j, base):
        return {"offset": float(th[0])}

    def torque(p, j, q, dq, tm, rate, slope):
        return np.full(q.shape[0], p["offset"])

    return Effect("torque_offset", "constant bias on the joint's effort", "none (constant)", "everywhere",
                  ("offset",), lambda j: {"offset": _u(j, "N m", "N")}, lambda j: (None,), None,
                  cols, params, lambda p, j: None, torque,
                  in_rigid_body_model=True, equivalent_to=("coulomb_asymmetry",))


def _viscous_nonlinear() -> Effect:
    def cols(ctx, j, p):
        v = ctx.dq[:, j - 1]
        return _on(j, np.sign(v) * np.abs(v) ** p)

    def params(th, p, j, base):
        return {"c": float(th[0]), "exponent": float(p)}

    def sanity(p, j):
        if not p["c"] > 0:
            return f"coefficient {p['c']:.4g} is not positive (damping would fall with speed)"
        return None

    def torque(p, j, q, dq, tm, rate, slope):
        v = dq[:, j - 1]
        return p["c"] * np.sign(v) * np.abs(v) ** p["exponent"]

    return Effect("viscous_nonlinear", "damping growing faster than linearly: c sign(dq) |dq|^n, n > 1",
                  "|dq|", "high speed", ("c",),
                  lambda j: {"c": _u(j, "N m (s/rad)^n", "N (s/m)^n"), "exponent": "1"},
                  lambda j: (1.5, 2.0, 3.0), "exponent", cols, params, sanity, torque)


CATALOGUE: dict[str, Effect] = {e.id: e for e in (
    _stiction(), _coulomb_asymmetry(), _position_friction(), _spring(), _payload(), _backlash(),
    _hysteresis(), _time_delay(), _torque_offset(), _viscous_nonlinear())}

IDS = tuple(CATALOGUE)


def describe() -> dict:
    """The catalogue as data (for reports and the model file)."""
    return {"version": CATALOGUE_VERSION,
            "effects": {e.id: {"description": e.description, "variable": e.variable, "regime": e.regime,
                               "grid": e.grid_name, "option": e.option_name,
                               "units_joint1": e.units(1), "units_joint3": e.units(3),
                               "absorbed_by_identified_model": e.in_rigid_body_model,
                               "equivalent_to": list(e.equivalent_to)} for e in CATALOGUE.values()}}


#: Why a controller does not feed an effect forward (`EffectCompensation`).
NOT_COMPENSATED = {
    "payload": "in the standard parameters (the rigid-body model carries it)",
    "backlash": "a play is crossed, not pushed against: its torque is the drive's own reversal history, "
                "which a feedforward torque cannot cancel",
    "time_delay": "a lag of the effort reading, not a load on the joint",
}


class EffectCompensation:
    """A model file's effects as a controller's feedforward, one control step at a time:
    ``comp(q, dq)`` -> (3,) torques (N m, N m, N) the effects add at the state (q, dq).

    The torques are the catalogue's own (`Effect.torque`, the smooth sign tanh(a dq / 2)
    with the model's slope a). A Dahl state is kept per hysteresis entry and advanced by
    the position change since the previous call (`dahl_step`, as `dahl_state`), so keep
    one object per arm and call it once per step with that step's state. ``skipped``
    lists the entries not fed forward with the reason (`NOT_COMPENSATED`).
    """

    def __init__(self, effects: list[dict], slope: float):
        self.slope = float(slope)
        self.entries = [e for e in effects if e["name"] not in NOT_COMPENSATED]
        self.skipped = [{"name": e["name"], "joint": int(e["joint"]), "reason": NOT_COMPENSATED[e["name"]]}
                        for e in effects if e["name"] in NOT_COMPENSATED]
        self._dahl = [0.0] * len(self.entries)
        self._q_last: np.ndarray | None = None

    def __bool__(self) -> bool:
        return bool(self.entries)

    def __call__(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        q, dq = np.asarray(q, float), np.asarray(dq, float)
        step = np.zeros(3) if self._q_last is None else q - self._q_last
        self._q_last = q.copy()
        out = np.zeros(3)
        for i, e in enumerate(self.entries):
            j = int(e["joint"]) - 1
            if e["name"] == "hysteresis":
                self._dahl[i] = dahl_step(self._dahl[i], step[j], e["params"]["travel"])
                out[j] += e["params"]["Fd"] * self._dahl[i]
            else:
                out += CATALOGUE[e["name"]].torque(e["params"], int(e["joint"]), q[None], dq[None],
                                                   slope=self.slope)[0]
        return out


def effects_torque(effects: list[dict], q, dq, tau_model=None, rate: float = 200.0, slope: float = 400.0,
                   exclude=("payload",), ddq=None, mass_diag=None) -> np.ndarray:
    """Sum of the torques (n, 3) of a model file's ``effects`` entries on raw samples.

    A payload is part of the rigid-body parameters (see ``payload_standard_delta``) and is
    excluded here. ``tau_model`` (n, 3) is needed for time_delay and backlash; backlash also
    uses the joint accelerations ``ddq`` (default: central differences of dq) and the model's
    mass-matrix diagonal on the samples ``mass_diag`` (n, 3) (default: the inertia in its
    parameters, the median configuration's).
    """
    q, dq = np.atleast_2d(q), np.atleast_2d(dq)
    out = np.zeros_like(q, dtype=float)
    for e in effects:
        if e["name"] in exclude:
            continue
        out += CATALOGUE[e["name"]].torque(e["params"], int(e["joint"]), q, dq, tau_model, rate, slope,
                                           ddq, mass_diag)
    return out
