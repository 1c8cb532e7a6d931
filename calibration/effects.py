"""The effect catalogue of the discrepancy workflow (issue 7): fixed, versioned, named physics.

Each effect is a class derived from `calibration.effect_model.Effect`, one physical component a rigid-body + viscous/Coulomb/offset model
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

import numpy as np

from calibration.effect_model import (Effect, EffectContext, _geom, _on, _on_k, _sig, _u,  # noqa: F401
                                      dahl_state, dahl_step, delayed, gap_torque)

#: 1.1: backlash returns the momentum at the contact and has a motor-side inertia (params changed).
#: 1.2: position_friction's level is a Fourier series of 1-4 harmonics of its period (params
#: a_sin, a_cos, harmonics added; 1.1 entries, one ripple as amplitude and phase, still evaluate).
#: 1.3: coulomb_asymmetry's levels follow its torque dFc (1 + sigma(dq)) / 2: Fc_pos = Fc + dFc
#: moving up, Fc_neg = Fc moving down (1.2 wrote Fc -/+ dFc/2; dFc, what is evaluated, unchanged).
CATALOGUE_VERSION = "1.3"

#: Bodies a payload is attributed to for joint 1, 2, 3 (rig.model.psm_dynamics.BODY_NAMES).
PAYLOAD_BODIES = ("yaw_link", "pitch_end", "tool")


# ----------------------------------------------------------------------------- the effects
class Stiction(Effect):
    id = "stiction"
    description = ("Stribeck / breakaway friction above Coulomb near zero velocity: "
                   "(Fs - Fc) exp(-(dq/vs)^2) sigma(dq)")
    variable, regime, linear_names, grid_name = "dq", "|dq| < 2 vs", ("dFs",), "vs"

    def units(self, j):
        return {"dFs": _u(j, "N m", "N"), "Fs": _u(j, "N m", "N"), "Fc": _u(j, "N m", "N"),
                "vs": _u(j, "rad/s", "m/s")}

    def grid(self, j):
        return _geom(0.002, 0.1, 7) if j < 3 else _geom(0.0004, 0.02, 7)

    def columns(self, ctx, j, vs):
        v = ctx.dq[:, j - 1]
        return _on(j, ctx.sign(v) * np.exp(-(v / vs) ** 2))

    def _params(self, th, vs, j, base):
        fc = base.get("Fc", 0.0)
        return {"dFs": float(th[0]), "Fs": float(fc + th[0]), "Fc": float(fc), "vs": float(vs)}

    def sanity(self, p, j):
        if not p["Fs"] >= p["Fc"] >= 0.0:
            return f"needs Fs >= Fc >= 0, got Fs {p['Fs']:.4g}, Fc {p['Fc']:.4g}"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        v = dq[:, j - 1]
        return p["dFs"] * _sig(v, slope) * np.exp(-(v / p["vs"]) ** 2)


class CoulombAsymmetry(Effect):
    id = "coulomb_asymmetry"
    description = "direction-dependent Coulomb level: Fc+ for dq > 0, Fc- for dq < 0"
    variable, regime, linear_names = "sign(dq)", "dq > 0 vs dq < 0", ("dFc",)
    in_rigid_body_model, equivalent_to = True, ("torque_offset",)

    def units(self, j):
        return {k: _u(j, "N m", "N") for k in ("dFc", "Fc_pos", "Fc_neg")}

    def columns(self, ctx, j, g):
        return _on(j, 0.5 * (1.0 + ctx.sign(ctx.dq[:, j - 1])))

    def _params(self, th, g, j, base):
        fc = base.get("Fc", 0.0)
        # The torque d (1 + sigma) / 2: the level moving up is raised by d, the one moving
        # down is the baseline's.
        return {"dFc": float(th[0]), "Fc_pos": float(fc + th[0]), "Fc_neg": float(fc)}

    def sanity(self, p, j):
        if min(p["Fc_pos"], p["Fc_neg"]) < 0:
            return f"a Coulomb level would be negative (Fc+ {p['Fc_pos']:.4g}, Fc- {p['Fc_neg']:.4g})"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        return p["dFc"] * 0.5 * (1.0 + _sig(dq[:, j - 1], slope))


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


class PositionFriction(Effect):
    id = "position_friction"
    description = ("Coulomb level varying with position: sigma(dq) f(q), f a Fourier series of period P "
                   "(sum over k <= K of a_k sin(2 pi k q / P) + b_k cos(2 pi k q / P))")
    variable, regime, linear_names, grid_name = "q (in motion)", "whole stroke", ("a_sin1", "a_cos1"), "period"
    option_name, nested_options = "harmonics", True

    def units(self, j):
        return {"amplitude": _u(j, "N m", "N"), "phase": "rad", "period": _u(j, "rad", "m"),
                "harmonics": "1", "a_sin": _u(j, "N m", "N"), "a_cos": _u(j, "N m", "N"),
                "lowest": _u(j, "N m", "N"), "Fc": _u(j, "N m", "N"), "relative_amplitude": "1"}

    def grid(self, j):
        return _geom(0.15, 2.0, 9) if j < 3 else _geom(0.015, 0.2, 9)

    def options(self, j):
        return FRICTION_HARMONICS

    def names(self, g):
        return tuple(n for k in range(1, int(g[1]) + 1) for n in (f"a_sin{k}", f"a_cos{k}"))

    def columns(self, ctx, j, g):
        period, n = g
        s = ctx.sign(ctx.dq[:, j - 1])
        return _on_k(j, [s * t for t in _harmonics(ctx.q[:, j - 1], period, n)])

    def _params(self, th, g, j, base):
        period, n = g
        a_sin, a_cos = th[0::2], th[1::2]
        fc = base.get("Fc", 0.0)
        f = friction_profile({"period": period, "a_sin": a_sin, "a_cos": a_cos}, np.linspace(0.0, period, 721))
        amp = float(np.max(np.abs(f)))
        return {"amplitude": amp, "phase": float(np.arctan2(a_cos[0], a_sin[0])), "period": float(period),
                "harmonics": int(n), "a_sin": [float(v) for v in a_sin], "a_cos": [float(v) for v in a_cos],
                "lowest": float(np.min(f)), "Fc": float(fc), "relative_amplitude": amp / fc if fc > 0 else float("inf")}

    def sanity(self, p, j):
        # The friction level Fc + f(q) must stay >= 0 (within a 20 % allowance).
        if -p["lowest"] > 1.2 * max(p["Fc"], 0.0):
            return (f"the friction level dips {-p['lowest']:.4g} below the Coulomb level {p['Fc']:.4g} "
                    "(it would turn negative)")
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        return _sig(dq[:, j - 1], slope) * friction_profile(p, q[:, j - 1])


class Spring(Effect):
    id = "spring"
    description = "torque proportional to position: k (q - q0) (cables, a balancing spring)"
    variable, regime, linear_names = "q", "whole stroke", ("k", "c0")

    def units(self, j):
        return {"k": _u(j, "N m/rad", "N/m"), "q0": _u(j, "rad", "m")}

    def columns(self, ctx, j, g):
        q = ctx.q[:, j - 1]
        return _on_k(j, [q, np.ones_like(q)])

    def _params(self, th, g, j, base):
        k = float(th[0])
        if th[1] == 0.0:
            # The constant part k q0 is not separable from the model's offset Fo here.
            return {"k": k, "q0": None}
        return {"k": k, "q0": float(-th[1] / k) if k != 0 else float("nan")}

    def sanity(self, p, j):
        if not p["k"] > 0:
            return f"stiffness {p['k']:.4g} is not positive (not a restoring spring)"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        return p["k"] * (q[:, j - 1] - (p["q0"] or 0.0))


def point_mass_parameters(com) -> np.ndarray:
    """(10,) standard parameters of a unit point mass at ``com`` (m, body frame): mass 1, first
    moments c and the inertia about the frame origin |c|^2 I - c c^T, in the regressor's order
    (m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz)."""
    c = np.asarray(com, float)
    Io = (c @ c) * np.eye(3) - np.outer(c, c)
    return np.array([1.0, c[0], c[1], c[2], Io[0, 0], Io[0, 1], Io[1, 1], Io[0, 2], Io[1, 2], Io[2, 2]])


#: A payload's centre must lie within this box (m, each axis of the body frame).
COM_BOX = 0.6


class Payload(Effect):
    id = "payload"
    description = ("unmodelled point mass m at c on the link of the joint (default the tool): "
                   "its gravity and its inertia m (|c|^2 I - c c^T)")
    variable, regime, linear_names, grid_name = "q (gravity), ddq", "whole workspace", ("m",), "com"
    uses_model, all_joints, in_rigid_body_model, nonlinear_dim, point_mass = True, True, True, 3, True

    def units(self, j):
        return {"mass": "kg", "com": "m (body joint frame)", "first_moment": "kg m", "body": ""}

    def columns(self, ctx, j, com):
        b = ctx.body_names.index(PAYLOAD_BODIES[j - 1])
        W = ctx.W_standard[:, 10 * b:10 * b + 10].reshape(-1, 3, 10)  # the body's ten columns
        if com is None:
            return W
        # A point mass at com: its gravity (first moments) and its inertia, per kg.
        return (W @ point_mass_parameters(com))[:, :, None]

    def _params(self, th, com, j, base):
        m = float(th[0])
        c = [float(x) for x in com]
        return {"mass": m, "com": c, "first_moment": [m * x for x in c], "body": PAYLOAD_BODIES[j - 1]}

    def sanity(self, p, j):
        if not p["mass"] > 0:
            return f"mass {p['mass']:.4g} kg is not positive"
        if not np.all(np.abs(p["com"]) < COM_BOX):
            return f"centre of mass {np.round(p['com'], 3).tolist()} m lies outside the arm"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        # A payload is a change of the rigid-body parameters, not an added torque term.
        raise ValueError("a payload changes the rigid-body parameters: use payload_standard_delta")


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


class Backlash(Effect):
    id = "backlash"
    description = ("dead zone at torque reversal: while the motor crosses the play of width b (driven relative "
                   "to the joint side by the transmitted torque over the joint side's inertia) the drive "
                   "transmits nothing, and the contact at the far face returns the joint side's lag in momentum")
    variable = "motor travel across the play after a torque reversal"
    regime = "crossing the play after each reversal of the transmitted torque"
    linear_names, grid_name, option_name = ("unloaded_fraction",), "width", "motor_fraction"
    uses_model, nonlinear_dim, needs_dynamics = True, 2, True

    def units(self, j):
        return {"width": _u(j, "rad", "m"), "unloaded_fraction": "1", "motor_fraction": "1",
                "motor_inertia": _u(j, "N m s^2/rad", "kg"), "inertia": _u(j, "N m s^2/rad", "kg"),
                "Fc": _u(j, "N m", "N"), "Fv": _u(j, "N m s/rad", "N s/m"), "stuck_velocity": _u(j, "rad/s", "m/s")}

    def grid(self, j):
        return _geom(0.002, 0.04, 7) if j < 3 else _geom(0.0003, 0.006, 7)

    def options(self, j):
        return MOTOR_FRACTIONS

    def columns(self, ctx, j, g):
        width, frac = g
        inertia = float(ctx.inertia[j - 1])
        if not inertia > 0:
            return _on(j, np.zeros(len(ctx.q)))
        fc, fv = ctx.friction[j - 1]
        return _on(j, gap_torque(ctx.tau_model[:, j - 1], ctx.ddq[:, j - 1], ctx.mass_diag[:, j - 1],
                                 ctx.dq[:, j - 1], ctx.rate, width, frac * inertia, (fc, fv), ctx.slope,
                                 float(ctx.deadband[j - 1])))

    def _params(self, th, g, j, base):
        width, frac = g
        return {"width": float(width), "unloaded_fraction": float(th[0]), "motor_fraction": float(frac),
                "motor_inertia": float(frac * base["inertia"]), "inertia": float(base["inertia"]),
                "Fc": float(base.get("Fc", 0.0)), "Fv": float(base.get("Fv", 0.0)),
                "stuck_velocity": float(base.get("stuck_velocity", 0.0))}

    def sanity(self, p, j):
        if not 0.2 <= p["unloaded_fraction"] <= 1.5:
            return (f"the load seen while crossing the gap drops by {p['unloaded_fraction']:.3g} of the "
                    "transmitted torque (a gap unloads by about 1)")
        if not p["inertia"] > 0:
            return f"the model's inertia on the joint is {p['inertia']:.3g}: the crossing is undefined"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        md = p["inertia"] if mass_diag is None else np.atleast_2d(mass_diag)[:, j - 1]
        return p["unloaded_fraction"] * gap_torque(tm[:, j - 1], ddq[:, j - 1], md, dq[:, j - 1], rate,
                                                   p["width"], p["motor_inertia"], (p["Fc"], p["Fv"]), slope,
                                                   p.get("stuck_velocity", 0.0))


class Hysteresis(Effect):
    id = "hysteresis"
    description = "Dahl pre-sliding friction: a state z -> Fd sign(dq) over a travel Fd / sigma0 after each reversal"
    variable = "q travel after a velocity reversal"
    regime = "first few travel constants after each reversal"
    linear_names, grid_name = ("Fd",), "travel"

    def units(self, j):
        return {"Fd": _u(j, "N m", "N"), "travel": _u(j, "rad", "m"), "sigma0": _u(j, "N m/rad", "N/m")}

    def grid(self, j):
        return _geom(0.0005, 0.03, 8) if j < 3 else _geom(0.0001, 0.006, 8)

    def columns(self, ctx, j, travel):
        return _on(j, dahl_state(ctx.q[:, j - 1], travel))

    def _params(self, th, travel, j, base):
        fd = float(th[0])
        return {"Fd": fd, "travel": float(travel), "sigma0": fd / travel if travel > 0 else float("nan")}

    def sanity(self, p, j):
        if not p["Fd"] > 0:
            return f"Dahl level {p['Fd']:.4g} is not positive"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        return p["Fd"] * dahl_state(q[:, j - 1], p["travel"])

    def step_torque(self, p, joint, q, dq, step, state, slope):
        """The Dahl state kept from step to step and advanced by the step's travel
        (`dahl_step`, as `dahl_state` does along a path)."""
        j = joint - 1
        state = dahl_step(state, step[j], p["travel"])
        out = np.zeros(3)
        out[j] += p["Fd"] * state
        return out, state


#: Delays (s) tried for ``time_delay``.
DELAY_GRID = (0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06)


class TimeDelay(Effect):
    id = "time_delay"
    description = "measured effort lagging the motion by d: tau(t - d)"
    variable, regime, linear_names, grid_name = "lag of the model torque", "fast torque changes", ("gain",), "delay"
    uses_model = True

    def units(self, j):
        return {"delay": "s", "grid_delay": "s", "gain": "1"}

    def grid(self, j):
        return DELAY_GRID

    def columns(self, ctx, j, delay):
        x = ctx.tau_model[:, j - 1]
        return _on(j, delayed(x, delay * ctx.rate) - x)

    def _params(self, th, delay, j, base):
        return {"delay": float(delay * th[0]), "grid_delay": float(delay), "gain": float(th[0])}

    def sanity(self, p, j):
        # To first order tau(t - d) - tau(t) = -d dtau/dt, so the gain and the grid delay trade
        # off (and the baseline refit takes up part of a delay): what is physical is that the
        # effort lags (d = gain x grid delay > 0) by no more than the catalogue's longest delay.
        if not 0.0 < p["delay"] <= DELAY_GRID[-1]:
            return (f"the implied delay {p['delay']:.3g} s is not a lag within (0, {DELAY_GRID[-1]:g}] s "
                    f"(gain {p['gain']:.3g} at {p['grid_delay']:g} s)")
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        x = tm[:, j - 1]
        return delayed(x, p["delay"] * rate) - x


class TorqueOffset(Effect):
    id = "torque_offset"
    description = "constant bias on the joint's effort"
    variable, regime, linear_names = "none (constant)", "everywhere", ("offset",)
    in_rigid_body_model, equivalent_to = True, ("coulomb_asymmetry",)

    def units(self, j):
        return {"offset": _u(j, "N m", "N")}

    def columns(self, ctx, j, g):
        return _on(j, np.ones(ctx.q.shape[0]))

    def _params(self, th, g, j, base):
        return {"offset": float(th[0])}

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        return np.full(q.shape[0], p["offset"])


class ViscousNonlinear(Effect):
    id = "viscous_nonlinear"
    description = "damping growing faster than linearly: c sign(dq) |dq|^n, n > 1"
    variable, regime, linear_names, grid_name = "|dq|", "high speed", ("c",), "exponent"

    def units(self, j):
        return {"c": _u(j, "N m (s/rad)^n", "N (s/m)^n"), "exponent": "1"}

    def grid(self, j):
        return (1.5, 2.0, 3.0)

    def columns(self, ctx, j, p):
        v = ctx.dq[:, j - 1]
        return _on(j, np.sign(v) * np.abs(v) ** p)

    def _params(self, th, p, j, base):
        return {"c": float(th[0]), "exponent": float(p)}

    def sanity(self, p, j):
        if not p["c"] > 0:
            return f"coefficient {p['c']:.4g} is not positive (damping would fall with speed)"
        return None

    def joint_torque(self, p, j, q, dq, tm, rate, slope, ddq=None, mass_diag=None):
        v = dq[:, j - 1]
        return p["c"] * np.sign(v) * np.abs(v) ** p["exponent"]


CATALOGUE: dict[str, Effect] = {e.id: e for e in (
    Stiction(), CoulombAsymmetry(), PositionFriction(), Spring(), Payload(), Backlash(),
    Hysteresis(), TimeDelay(), TorqueOffset(), ViscousNonlinear())}

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
    with the model's slope a), one step at a time (`Effect.step_torque`): an effect with a
    state of its own (hysteresis: the Dahl state) advances it by the position change since
    the previous call, so keep one object per arm and call it once per step with that
    step's state. ``skipped``
    lists the entries not fed forward with the reason (`NOT_COMPENSATED`).
    """

    def __init__(self, effects: list[dict], slope: float):
        self.slope = float(slope)
        self.entries = [e for e in effects if e["name"] not in NOT_COMPENSATED]
        self.skipped = [{"name": e["name"], "joint": int(e["joint"]), "reason": NOT_COMPENSATED[e["name"]]}
                        for e in effects if e["name"] in NOT_COMPENSATED]
        self._state = [0.0] * len(self.entries)   # each entry's own state (a Dahl state)
        self._q_last: np.ndarray | None = None

    def __bool__(self) -> bool:
        return bool(self.entries)

    def __call__(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        q, dq = np.asarray(q, float), np.asarray(dq, float)
        step = np.zeros(3) if self._q_last is None else q - self._q_last
        self._q_last = q.copy()
        out = np.zeros(3)
        for i, e in enumerate(self.entries):
            torque, self._state[i] = CATALOGUE[e["name"]].step_torque(e["params"], int(e["joint"]), q, dq, step,
                                                                     self._state[i], self.slope)
            out += torque
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
