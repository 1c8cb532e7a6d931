"""Seeded generator of hidden-effect test data for the discrepancy workflow (issue 7).

This module is the *experimenter*: it sets up the simulated rig (`rig.sim.world.SimWorld`) with
an effect hidden in the plant, streams an exciting trajectory through the joint PID at
1 kHz with servo_jp, and records what the dVRK would report (measured q, dq, effort) at
200 Hz. It returns only those measured arrays plus, separately, the truth for scoring.
`calibration.discrepancy` never imports this module: the workflow sees the arrays only.

Cases are catalogue effects on one joint, two effects at once, the null case, and effects
outside the catalogue (a time-periodic torque disturbance, a cross-joint viscous coupling)
for which the honest answer is "unexplained". Magnitudes are drawn from a seeded range
around a typical size per joint (N m for joints 1-2, N for joint 3).

Effects the sim applies to all joints at once (time delay) or to the tool only (payload)
are placed on one joint here: the delay by shifting that joint's recorded effort channel
as the sim's effort history does, a payload by a point mass on the body the joint carries.
Disturbances outside the catalogue are written into the plant's constant-load row every
step (the sim's `torque_offset` input), so the PID really fights them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from rig.model.plant_effects import HiddenEffects
from rig.model.psm_dynamics import Body, PSMParameters
from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN
from rig.sim import kernel as sim_kernel
from rig.sim.world import ArmSpec, SensorNoise, SimWorld

GENERATOR_VERSION = 2
ARM = "PSM1"
RATE = 200.0           # Hz, the recorded rate (the WPI data's)
SIM_DT = 1e-3          # s, the dVRK servo period
N_SAMPLES = 6000       # 30 s at 200 Hz

#: Catalogue effects the generator can hide (ids of calibration.effects).
CATALOGUE_CASES = ("stiction", "coulomb_asymmetry", "position_friction", "spring", "payload", "backlash",
                   "hysteresis", "time_delay", "torque_offset", "viscous_nonlinear")
#: Effects outside the catalogue.
OUTSIDE_CASES = ("sinusoidal_disturbance", "cross_coupling")

# Typical sizes per joint; a case draws 0.8-1.25 times these. Chosen about ten times the
# residual the sensor noise and friction switching leave on a model without effects.
_SIZE = {
    "stiction": np.array([0.20, 0.25, 1.0]),            # Fs - Fc, N m / N
    "coulomb_asymmetry": np.array([0.12, 0.15, 0.6]),   # Fc+ - Fc-
    "position_friction": np.array([0.9, 0.9, 0.9]),     # relative amplitude of Fc(q)
    "spring": np.array([0.8, 1.0, 25.0]),               # N m/rad, N/m
    "payload": np.array([0.4, 0.3, 0.25]),              # kg
    "backlash": np.array([0.01, 0.01, 0.002]),          # rad, m (total play)
    "hysteresis": np.array([0.12, 0.15, 0.6]),          # Dahl level Fd
    "time_delay": np.array([0.02, 0.02, 0.02]),         # s
    "torque_offset": np.array([0.12, 0.15, 0.6]),
    "viscous_nonlinear": np.array([0.6, 0.8, 20.0]),    # N m s^2/rad^2, N s^2/m^2
    "sinusoidal_disturbance": np.array([0.12, 0.15, 0.6]),
    "cross_coupling": np.array([0.3, 0.3, 2.0]),        # N m s/rad from the next joint's velocity
}
# Coulomb level of the plant's nominal friction (rig.model.psm_dynamics.DriveParameters.Fc):
# position-dependent friction scales it, so joints 1-2 would see only ~0.05 N m. The generator
# raises the plant's Coulomb level on that joint to make the effect as large as the others.
_POSFRIC_FC = np.array([0.15, 0.15, 0.6])
# A play on the pitch axis opens only where the torque the drive transmits changes sign. The
# real PSM's pitch is balanced (the WPI data's joint-2 effort: median -0.10 N m, range
# -1.65..1.41 N m); the simulated arm's is not (0.9..2.5 N m on the generator's trajectories),
# so a joint-2 play would never open. A joint-2 backlash case (and its twin) gets a constant
# counter-torque on the pitch axis, N m, that leaves its load crossing zero.
_PITCH_BALANCE = 1.8
# Bodies a payload sits on for an effect attributed to joint 1, 2, 3.
_PAYLOAD_BODY = ("yaw_link", "pitch_end", "tool")


@dataclass
class HiddenCase:
    """One hidden case: effects [(id, joint 1-3)] (empty for the null case) and a seed."""

    effects: tuple[tuple[str, int], ...]
    seed: int

    @property
    def label(self) -> str:
        return "+".join(f"{e}@{j}" for e, j in self.effects) or "null"


@dataclass
class Recorded:
    """What the workflow may see: measured arrays (n, 3) at ``rate`` Hz, SI units."""

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    rate: float


@dataclass
class Truth:
    """What only the scorer may see: the effects with their drawn parameters."""

    case: HiddenCase
    params: list[dict] = field(default_factory=list)
    #: The joint side's velocity (n, 3) at the recorded samples (rad/s, m/s): with a play it
    #: differs from the encoder's (the motor side's) while the play is open.
    joint_velocity: np.ndarray | None = None


def trajectory(seed: int, duration: float, fill: float = 0.55):
    """A seeded multi-sine per joint within Table 4.2's limits: q, dq, ddq as functions of t.

    Four sines per joint at 0.06-0.5 Hz with random phases: reversals of every joint at
    many positions and speeds (what friction effects need) for far less set-up than an
    optimised Fourier design. Joint 3 stays in its middle (0.04-0.2 m) where the tool is
    well inside the cannula.
    """
    rng = np.random.default_rng(7919 + seed)
    freqs = rng.uniform(0.06, 0.5, size=(3, 4))
    # The insertion stroke is short: faster sines keep it moving (a joint that crawls
    # spends its time stuck at reversals, where no friction model predicts the effort).
    freqs[2] = rng.uniform(0.2, 0.8, size=4)
    phases = rng.uniform(0, 2 * np.pi, size=(3, 4))
    amps = rng.uniform(0.5, 1.0, size=(3, 4)) / freqs  # equal velocity share per sine
    lo, hi = np.array(Q_MIN, float), np.array(Q_MAX, float)
    lo[2], hi[2] = 0.04, 0.20
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    t = np.arange(0.0, duration, 0.01)
    w = 2 * np.pi * freqs
    q_raw = np.einsum("jk,tjk->tj", amps, np.sin(w[None] * t[:, None, None] + phases[None]))
    dq_raw = np.einsum("jk,tjk->tj", amps * w, np.cos(w[None] * t[:, None, None] + phases[None]))
    s = np.minimum(fill * half / np.abs(q_raw).max(0), 0.5 * DQ_MAX / np.abs(dq_raw).max(0))
    s[2] = min(s[2], fill * half[2] / np.abs(q_raw[:, 2]).max())
    A = amps * s[:, None]

    def sample(tt):
        """q, dq, ddq at times ``tt`` (s): (3,) each for a scalar, (n, 3) for an array."""
        arg = w * np.asarray(tt, float)[..., None, None] + phases
        return (mid + (A * np.sin(arg)).sum(-1), (A * w * np.cos(arg)).sum(-1),
                (-A * w * w * np.sin(arg)).sum(-1))

    return sample


def draw_case_parameters(case: HiddenCase) -> list[dict]:
    """The effects' parameters drawn from the case seed (joint-indexed sizes, see _SIZE)."""
    rng = np.random.default_rng(104729 + case.seed)
    out = []
    for name, joint in case.effects:
        j = joint - 1
        size = float(_SIZE[name][j] * rng.uniform(0.8, 1.25))
        p: dict = {"effect": name, "joint": joint, "size": size}
        if name == "stiction":
            p["stribeck_velocity"] = float(rng.uniform(0.01, 0.03) * (0.4 if j == 2 else 1.0))
        elif name == "position_friction":
            span = (Q_MAX[j] - Q_MIN[j]) if j < 2 else 0.16
            p["period"] = float(span * rng.uniform(0.25, 0.45))
        elif name == "spring":
            p["rest"] = float(rng.uniform(-0.3, 0.3) if j < 2 else rng.uniform(0.06, 0.18))
        elif name == "payload":
            # A point mass off the body's joint axis so it loads that joint under gravity.
            p["com"] = {0: [0.0, -0.15, -0.1], 1: [0.35, 0.0, 0.0], 2: [0.0, 0.05, -0.1]}[j]
        elif name == "hysteresis":
            p["stiffness"] = float(size / (rng.uniform(0.002, 0.006) if j < 2 else rng.uniform(4e-4, 1.2e-3)))
        elif name == "sinusoidal_disturbance":
            p["frequency"] = float(rng.uniform(0.7, 1.6))   # Hz, unrelated to the motion
        out.append(p)
    return out


def _add_point_mass(params: PSMParameters, body: str, mass: float, com) -> PSMParameters:
    b = params.bodies[body]
    added = pin.Inertia(b.mass, np.asarray(b.com, float), np.asarray(b.inertia, float)) + \
        pin.Inertia(mass, np.asarray(com, float), np.zeros((3, 3)))
    bodies = dict(params.bodies)
    bodies[body] = Body(float(added.mass), np.array(added.lever), np.array(added.inertia))
    return replace(params, bodies=bodies)


def _plant(case_params: list[dict], twin: bool = False) -> tuple[PSMParameters, HiddenEffects, dict]:
    """Plant parameters, the sim's hidden effects and the generator-side extras. ``twin``:
    the same plant set-up with every effect's size 0 (the case's noise-floor twin)."""
    params = PSMParameters()
    eff = HiddenEffects()
    extra = {"delay": np.zeros(3), "sinusoid": None, "coupling": None}
    for p in case_params:
        name, j, size = p["effect"], p["joint"] - 1, (0.0 if twin else p["size"])
        if name == "stiction":
            Fc = params.drive.Fc
            eff.stiction[j] = Fc[j] + size
            eff.stribeck_velocity[j] = p["stribeck_velocity"]
        elif name == "coulomb_asymmetry":
            eff.coulomb_asymmetry[j] = size
        elif name == "position_friction":
            fc = params.drive.Fc.copy()
            fc[j] = max(fc[j], _POSFRIC_FC[j])
            params = replace(params, drive=replace(params.drive, Fc=fc))
            eff.position_friction[j] = min(size, 0.95)
            eff.position_friction_period[j] = p["period"]
        elif name == "spring":
            eff.spring[j] = size
            eff.spring_rest[j] = p["rest"]
        elif name == "payload":
            params = _add_point_mass(params, _PAYLOAD_BODY[j], size, p["com"])
        elif name == "backlash":
            eff.backlash[j] = size
            if j == 1:
                fo = params.drive.Fo.copy()
                fo[1] -= _PITCH_BALANCE
                params = replace(params, drive=replace(params.drive, Fo=fo))
        elif name == "hysteresis":
            eff.hysteresis[j] = size
            eff.hysteresis_stiffness[j] = p["stiffness"]
        elif name == "time_delay":
            extra["delay"][j] = size
        elif name == "torque_offset":
            eff.torque_offset[j] = size
        elif name == "viscous_nonlinear":
            eff.viscous_nonlinear[j] = size
        elif name == "sinusoidal_disturbance":
            extra["sinusoid"] = (j, size, p["frequency"])
        elif name == "cross_coupling":
            extra["coupling"] = (j, size)
        else:
            raise ValueError(f"unknown hidden effect {name!r}")
    return params, eff, extra


def case_plant(case: HiddenCase) -> tuple[PSMParameters, HiddenEffects]:
    """The simulated plant of ``case`` (for a controller run on it; the recorded effort's
    generator-side delay and the disturbances outside the catalogue are not part of it)."""
    params, eff, _ = _plant(draw_case_parameters(case))
    return params, eff


def generate(case: HiddenCase, n_samples: int = N_SAMPLES, rate: float = RATE,
             noise: SensorNoise | None = None, trajectory_seed: int | None = None,
             twin: bool = False, excitation=None, plant=None) -> tuple[Recorded, Truth]:
    """Run the simulated rig on ``case`` and record measured q, dq, effort at ``rate`` Hz.

    ``excitation`` (a `calibration.excitation.FourierTrajectory`) replaces the seeded
    multi-sine as the commanded trajectory; the seed then sets the sensor noise only.

    ``trajectory_seed`` defaults to the case seed: a case and its twin (``twin=True``: the
    same seed and plant set-up, every effect's size 0) follow the same trajectory with the
    same sensor-noise draws, which is how the bench knows the noise floor of each case. The
    twin differs from the null case only where the set-up itself changes the plant: a
    position-dependent friction case raises the joint's Coulomb level (see _POSFRIC_FC), and
    its twin keeps that level without the ripple; a joint-2 backlash case balances the pitch
    axis (see _PITCH_BALANCE), and so does its twin.

    ``plant`` = (PSMParameters, HiddenEffects) replaces the case's plant (a model file's,
    `rig.model.model_file.IdentifiedModel.plant`): the same trajectory and noise draws on another
    plant, to compare what that model's simulated rig records with what the case recorded.
    """
    case_params = draw_case_parameters(case)
    params, eff, extra = _plant(case_params, twin)
    if plant is not None:
        params, eff = plant
        extra = {"delay": np.zeros(3), "sinusoid": None, "coupling": None}
    tseed = case.seed if trajectory_seed is None else trajectory_seed
    traj = trajectory(tseed, n_samples / rate + 1.0) if excitation is None else _fourier_sampler(excitation)
    q0, dq0, _ = traj(0.0)
    spec = ArmSpec(ARM, params=params, effects=eff, noise=noise or SensorNoise(), q0=q0)
    world = SimWorld([spec], obj=None, seed=tseed, dt=SIM_DT)
    world.set_state(ARM, q0, dq0)
    decim = int(round(1.0 / (rate * SIM_DT)))
    # Per-joint delay of the recorded effort (s -> steps): a ring of the applied efforts,
    # as the sim keeps for its own (all-joint) delay.
    delay_steps = np.round(extra["delay"] / SIM_DT).astype(int)
    ring = np.zeros((int(delay_steps.max()) + 1, 3))
    row = sim_kernel.CONSTANT_ROWS.index("offset")
    base_offset = world._constants[row].copy()
    settle = int(round(0.5 / SIM_DT))   # let the PID's integrator settle before recording
    total = settle + n_samples * decim
    Qd, DQd, _ = traj(np.arange(total) * SIM_DT)
    out_q = np.empty((n_samples, 3))
    out_dq = np.empty((n_samples, 3))
    out_tau = np.empty((n_samples, 3))
    out_joint = np.empty((n_samples, 3))
    cols = np.arange(3)
    k_out = 0
    for k in range(total):
        world.servo_jp(ARM, Qd[k], DQd[k])
        if extra["sinusoid"] is not None or extra["coupling"] is not None:
            load = base_offset.copy()
            if extra["sinusoid"] is not None:
                j, a, f = extra["sinusoid"]
                load[j] += a * np.sin(2 * np.pi * f * k * SIM_DT)
            if extra["coupling"] is not None:
                j, c = extra["coupling"]
                load[j] += c * world.dq[(j + 1) % 3]
            world._constants[row] = load
        world.step()
        slot = k % len(ring)
        ring[slot] = world.tau_applied[:3]
        if k >= settle and (k - settle) % decim == 0:
            q, dq, tau = world.measured_js(ARM)
            # measured = applied + noise: swap the applied effort for the delayed one.
            tau = tau - ring[slot] + ring[(slot - delay_steps) % len(ring), cols]
            out_q[k_out], out_dq[k_out], out_tau[k_out] = q, dq, tau
            out_joint[k_out] = world.true_state(ARM)[1]
            k_out += 1
    return Recorded(out_q, out_dq, out_tau, rate), Truth(case, case_params, out_joint)


def reference_seed(seed: int) -> int:
    """Seed of the reference (model identification) run that goes with a case seed: another
    trajectory on the same plant without effects, as a lab's earlier `rig identify`."""
    return 1_000_003 + seed


def _fourier_sampler(ft):
    """A FourierTrajectory as the generator's trajectory function: (3,) arrays for a scalar
    time, (n, 3) for an array."""
    def sample(tt):
        q, dq, ddq = ft.sample(tt)
        return (q[0], dq[0], ddq[0]) if np.ndim(tt) == 0 else (q, dq, ddq)
    return sample


#: The optimised excitation of the reference runs' identification (thesis 5.3), designed once
#: by `design_reference_excitation` and stored with how it was made.
REFERENCE_EXCITATION_PATH = Path(__file__).with_name("reference_excitation.json")
#: Its design: the thesis' 0.13 Hz, 5 harmonics, 30 s; joint 3 inside the generator's band
#: (0.04-0.20 m, where the multi-sines keep the tool) and every joint at half its velocity
#: limit, as the multi-sines are, so that what the reference model learns about friction
#: holds at the speeds the cases run at.
REFERENCE_EXCITATION_DESIGN = {"frequency_hz": 0.13, "harmonics": 5, "duration": 30.0, "velocity_fraction": 0.5,
                               "q3_band": [0.04, 0.20], "starts": 2, "iterations": 60, "seed": 0}


def design_reference_excitation(path: Path = REFERENCE_EXCITATION_PATH) -> dict:
    """Design the reference excitation (log condition number of the base regressor, SLSQP,
    `calibration.excitation`) and write it to ``path``; ~30 s."""
    from calibration.base_params import base_parameters_of
    from calibration.excitation import ExcitationDesigner
    from rig.model.psm_dynamics import PSMDynamics

    d = REFERENCE_EXCITATION_DESIGN
    model = PSMDynamics()
    model.slope = 400.0
    base = base_parameters_of(model.regressor_batch, model, Q_MIN, Q_MAX, DQ_MAX)
    lo, hi = np.array(Q_MIN, float), np.array(Q_MAX, float)
    lo[2], hi[2] = d["q3_band"]
    designer = ExcitationDesigner(model.regressor_batch, base.independent, lo, hi,
                                  d["velocity_fraction"] * np.asarray(DQ_MAX, float),
                                  frequency_hz=d["frequency_hz"], harmonics=d["harmonics"],
                                  duration=d["duration"], rate=RATE)
    # No time budget: every start runs, so the design is the same on any machine.
    res = designer.optimise(n_starts=d["starts"], seed=d["seed"], maxiter=d["iterations"], time_budget=1e9)
    doc = {"design": d, "trajectory": res.trajectory.to_dict(), "condition": res.condition_full,
           "limit_use": res.limit_use, "seconds": res.seconds}
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return doc


def reference_excitation(path: Path = REFERENCE_EXCITATION_PATH):
    """The stored reference excitation (a FourierTrajectory)."""
    from calibration.excitation import FourierTrajectory

    doc = json.loads(path.read_text())
    if doc.get("design") != REFERENCE_EXCITATION_DESIGN:
        raise ValueError(f"{path} was designed with {doc.get('design')}, not {REFERENCE_EXCITATION_DESIGN}: "
                         "run `python -m calibration.hidden_effects --design-reference`")
    return FourierTrajectory.from_dict(doc["trajectory"])


def reference_runs(seed: int) -> list[Recorded]:
    """The null runs a reference model is identified on for a case seed, as a lab would: the
    optimised excitation (a well-conditioned regressor: every inertial and gravity parameter
    pinned down) and a multi-sine of the kind the cases use (the friction at their speeds and
    reversal rates). Different seeds from every case, null and calibration run."""
    multisine, _ = generate(HiddenCase((), reference_seed(seed)))
    excited, _ = generate(HiddenCase((), 2_000_003 + seed), excitation=reference_excitation())
    return [multisine, excited]


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--design-reference"]:
        out = design_reference_excitation()
        print(f"condition {out['condition']:.1f}, limit use {out['limit_use']}, {out['seconds']:.0f} s "
              f"-> {REFERENCE_EXCITATION_PATH}")
    else:
        print("usage: python -m calibration.hidden_effects --design-reference")
