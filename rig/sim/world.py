"""The simulated rig: PSM plants, their controllers, the object between the tool tips, markers.

Every fake device reads this one world. It is deterministic from a seed, runs on its own
clock (faster than real time unless paced to the wall clock) and knows its true
parameters, so calibration and identification can be checked against truth.

Physics, per time step h (default 1 ms, the dVRK's servo rate):
* all arms live in one Pinocchio model (one CRBA and one bias-force pass per step for
  the whole rig); each arm is the open tree of `rig.model.psm_dynamics` projected by G;
* smooth torques (viscous, offset, spring, non-linear damping, Dahl pre-sliding, object
  forces J^T F) are integrated semi-implicitly; dry friction (Coulomb, Stribeck,
  direction- and position-dependent levels) is an impulse bounded per joint and solved by
  projected Gauss-Seidel, so a joint really sticks until the breakaway force is exceeded;
* each joint has the dVRK's PID behind position commands (servo_jp, move_jp) and takes
  efforts directly behind servo_jf; efforts saturate at the drive limit;
* the encoder reads the motor side: with backlash the motor and the joint are two bodies
  joined by a dead-zone spring;
* measured positions are quantised, velocities and efforts noisy; the measured effort is
  the commanded one (the dVRK converts motor current), optionally delayed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from rig.model import psm_kinematics as K
from rig.model.plant_effects import HiddenEffects
from rig.model.psm_dynamics import COUPLING, PSMParameters, add_psm_tree
from rig.sim import kernel as sim_kernel

WORLD_GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass
class SensorNoise:
    """Encoder quantum and noise levels (standard deviations)."""

    position_quantum: np.ndarray = field(default_factory=lambda: np.array([2e-5, 2e-5, 2e-6]))
    velocity_noise: np.ndarray = field(default_factory=lambda: np.array([2e-3, 2e-3, 3e-4]))
    effort_noise: np.ndarray = field(default_factory=lambda: np.array([5e-3, 5e-3, 1e-2]))
    effort_quantum: np.ndarray = field(default_factory=lambda: np.array([1e-3, 1e-3, 2e-3]))

    @staticmethod
    def off() -> "SensorNoise":
        z = np.zeros(3)
        return SensorNoise(z.copy(), z.copy(), z.copy(), z.copy())


@dataclass
class PIDGains:
    """The joint PID behind position commands (dVRK-like; N m/rad, N m s/rad, N m/(rad s))."""

    kp: np.ndarray = field(default_factory=lambda: np.array([200.0, 200.0, 600.0]))
    kd: np.ndarray = field(default_factory=lambda: np.array([8.0, 8.0, 25.0]))
    ki: np.ndarray = field(default_factory=lambda: np.array([300.0, 300.0, 900.0]))
    integral_limit: np.ndarray = field(default_factory=lambda: np.array([2.0, 2.0, 6.0]))  # N m, N


@dataclass
class ArmSpec:
    name: str
    base: np.ndarray = field(default_factory=lambda: np.eye(4))  # PSM frame 0 in the world (4x4)
    params: PSMParameters = field(default_factory=PSMParameters)
    effects: HiddenEffects = field(default_factory=HiddenEffects)
    noise: SensorNoise = field(default_factory=SensorNoise)
    pid: PIDGains = field(default_factory=PIDGains)
    effort_limit: np.ndarray = field(default_factory=lambda: np.array([5.0, 5.0, 15.0]))
    q0: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.12]))


@dataclass
class ObjectSpec:
    """A massless spring-damper between tool tips (thesis eq. 6.1).

    `kind` "spring" pushes and pulls; "string" only pulls (slack below its rest length).
    With three arms the object is a triangle of such elements, one per pair of arms.
    """

    arms: tuple[str, ...] = ("PSM1", "PSM2")
    stiffness: float = 2450.0   # N/m
    damping: float = 5.0        # N s/m
    rest_length: float | None = None  # m; None: the tip distance when attached
    kind: str = "spring"


@dataclass
class MarkerBody:
    """Three markers rigidly on a frame of an arm (or the world): a mocap rigid body."""

    name: str
    arm: str | None          # None: fixed in the world
    frame: str               # a frame of rig.model.psm_kinematics.frames(), or "world"
    offsets: np.ndarray      # 3 x 3 marker positions in that frame (m)


def default_marker_bodies(arm: str) -> list[MarkerBody]:
    """Three markers per link as in thesis 4.1.1 (Figure 4.1)."""
    tri = np.array([[0.03, 0.0, 0.01], [-0.015, 0.026, 0.01], [-0.015, -0.026, 0.025]])
    return [
        MarkerBody(f"{arm}_yaw", arm, "2", tri + [0.0, 0.05, 0.0]),
        MarkerBody(f"{arm}_pitch_back", arm, "3", tri * 0.8 + [-0.06, 0.0, 0.04]),
        MarkerBody(f"{arm}_pitch_bottom", arm, "4", tri + [-0.25, 0.0, 0.05]),
        MarkerBody(f"{arm}_pitch_end", arm, "5", tri + [-0.12, 0.0, 0.05]),
        MarkerBody(f"{arm}_tool", arm, "tip", tri + [0.0, 0.0, -0.35]),
    ]


class _Arm:
    """Per-arm bookkeeping of the world (not a public API)."""

    def __init__(self, spec: ArmSpec, index: int, rng: np.random.Generator, dt: float, params: PSMParameters):
        self.spec = spec
        self.index = index
        self.sl = slice(3 * index, 3 * index + 3)
        self.params = params
        self.rng = rng
        self.delay_steps = np.round(np.broadcast_to(np.asarray(spec.effects.time_delay, float), (3,)) / dt).astype(np.int64)
        self.columns = np.arange(self.sl.start, self.sl.stop)
        self.rcm_world = np.asarray(spec.base, float) @ K.RCM_FRAME


class SimWorld:
    """N PSM plants, their controllers, an object between the tips and mocap markers.

    Call `step()` once per tick (`dt` seconds) or `advance(duration)`. Devices read through
    `measured_js(name)`, `tip_world(name)`, `tension()`, `marker_positions()`.
    """

    def __init__(self, arms: list[ArmSpec], obj: ObjectSpec | None = None, seed: int = 0,
                 dt: float = 1e-3, marker_bodies: list[MarkerBody] | None = None,
                 gravity: np.ndarray = WORLD_GRAVITY, pace: bool = False):
        if not arms:
            raise ValueError("a simulated rig needs at least one arm")
        names = [a.name for a in arms]
        if len(set(names)) != len(names):
            raise ValueError(f"arm names must be unique, got {names}")
        self.dt = float(dt)
        self.t = 0.0
        self.steps = 0
        self.seed = seed
        self.pace = pace
        self._wall_start: float | None = None
        root = np.random.default_rng(seed)
        self.model = pin.Model()
        self.model.gravity = pin.Motion(np.asarray(gravity, float), np.zeros(3))
        self.arms: dict[str, _Arm] = {}
        joint_rows = []
        for i, spec in enumerate(arms):
            params = spec.params
            if spec.effects.payload_mass > 0:
                params = params.with_payload(spec.effects.payload_mass, spec.effects.payload_com)
            joint_rows.append(add_psm_tree(self.model, params, np.asarray(spec.base, float), prefix=spec.name + "/"))
            self.arms[spec.name] = _Arm(spec, i, np.random.default_rng(root.integers(2**63)), self.dt, params)
        self.names = names
        self.data = self.model.createData()
        n3 = 3 * len(arms)
        # q_tree = G q for all arms: block-diagonal coupling, rows in Pinocchio's joint order.
        self.G = np.zeros((self.model.nv, n3))
        for i, ids in enumerate(joint_rows):
            for row, jid in enumerate(ids):
                self.G[self.model.joints[jid].idx_v, 3 * i:3 * i + 3] = COUPLING[row]
        self._stack_constants()
        # State rows (views into one array the kernel updates in place): joint side (q, dq),
        # motor/encoder side (qm, dqm), Dahl friction, controller set-points and efforts.
        self._state = np.zeros((len(sim_kernel.STATE_ROWS), n3))
        (self.q, self.dq, self.qm, self.dqm, self.dahl, self.q_des, self.dq_des, self.integral,
         self.tau_cmd, self.tau_applied) = self._state
        self.q[:] = np.concatenate([np.asarray(a.spec.q0, float) for a in self.arms.values()])
        self.qm[:] = self.q
        self.q_des[:] = self.q
        self.modes = np.full(len(arms), sim_kernel.MODE_POSITION, dtype=np.int64)
        self._obj = np.zeros(3)
        self._history = np.zeros((max(int(a.delay_steps.max()) for a in self.arms.values()) + 1, n3))
        self._history_pos = 0
        self.object: ObjectSpec | None = None
        self._edges = np.zeros((0, 2), dtype=np.int64)
        self._edge_names: list[tuple[str, str]] = []
        self._rest = np.zeros(0)
        self.tensions = np.zeros(0)
        if obj is not None:
            self.attach_object(obj)
        self.marker_bodies = marker_bodies if marker_bodies is not None else [
            mb for name in self.names for mb in default_marker_bodies(name)
        ] + [MarkerBody("world", None, "world", np.array([[0.3, 0.2, 0.0], [0.25, 0.28, 0.0], [0.35, 0.26, 0.02]]))]

    def _stack_constants(self) -> None:
        arms = list(self.arms.values())
        eff = [a.spec.effects for a in arms]

        def cat(attr: str) -> np.ndarray:
            return np.concatenate([np.asarray(getattr(e, attr), float) for e in eff])

        self.Ia = np.concatenate([a.params.drive.Ia for a in arms])
        self.Fc = np.concatenate([a.params.drive.Fc for a in arms])
        self.Fv = np.concatenate([a.params.drive.Fv for a in arms])
        self.Fo = np.concatenate([a.params.drive.Fo for a in arms])
        self.Fs = np.maximum(cat("stiction"), self.Fc)
        self.vs = cat("stribeck_velocity")
        self.asym = cat("coulomb_asymmetry")
        self.posfric = cat("position_friction")
        self.posfric_period = cat("position_friction_period")
        self.k_spring = cat("spring")
        self.q_spring = cat("spring_rest")
        self.offset = cat("torque_offset")
        self.visc2 = cat("viscous_nonlinear")
        self.visc_exp = cat("viscous_exponent")
        self.profile_period = cat("friction_profile_period")
        # (harmonic, joint) rows of the absolute friction profile.
        profile_sin = np.concatenate([np.asarray(e.friction_profile_sin, float) for e in eff]).T
        profile_cos = np.concatenate([np.asarray(e.friction_profile_cos, float) for e in eff]).T
        self.dahl_level = cat("hysteresis")
        self.dahl_sigma = cat("hysteresis_stiffness")
        self.backlash = cat("backlash")
        # With backlash part of the rotor inertia sits on the motor side of the play: half of
        # it unless given (the rest turns with the joint side).
        motor = cat("backlash_motor_inertia")
        motor = np.where(np.isnan(motor), 0.5 * self.Ia, np.clip(motor, 0.0, self.Ia))
        self.Im = np.where(self.backlash > 0, motor, 1.0)
        self.Ij = np.where(self.backlash > 0, self.Ia - motor, self.Ia)
        # Transmission stiffness outside the play (N m/rad, N/m) and its damping. The kernel
        # integrates this contact implicitly for the motor-joint pair (an explicit step was
        # unstable in the damping: c h / Im = 1.33 on joint 3), so any values are stable.
        self.backlash_k = np.tile([1.0e4, 1.0e4, 5.0e4], len(arms))
        self.backlash_c = np.tile([20.0, 20.0, 100.0], len(arms))
        self.kp = np.concatenate([a.spec.pid.kp for a in arms])
        self.kd = np.concatenate([a.spec.pid.kd for a in arms])
        self.ki = np.concatenate([a.spec.pid.ki for a in arms])
        self.ilim = np.concatenate([a.spec.pid.integral_limit for a in arms])
        self.effort_limit = np.concatenate([np.asarray(a.spec.effort_limit, float) for a in arms])
        self.quantum = np.concatenate([a.spec.noise.position_quantum for a in arms])
        self.bases = np.array([a.rcm_world for a in arms])
        self.r_offset = K.L_TOOL - K.L_RCC
        rows = {f"profile_{kind}{k + 1}": table[k] for kind, table in (("sin", profile_sin), ("cos", profile_cos))
                for k in range(sim_kernel.PROFILE_HARMONICS)}
        self._constants = np.array([rows[r] if r in rows else
                                    getattr(self, {"period": "posfric_period", "kspring": "k_spring",
                                                   "qspring": "q_spring", "effort_limit": "effort_limit"}.get(r, r))
                                    for r in sim_kernel.CONSTANT_ROWS])

    # -- object ---------------------------------------------------------------------------
    def attach_object(self, obj: ObjectSpec) -> None:
        """Attach the object between the named arms' tips (rest length: the distance now, if unset)."""
        for name in obj.arms:
            if name not in self.arms:
                raise ValueError(f"object names arm {name!r}; the rig has {self.names}")
        if obj.kind not in ("spring", "string"):
            raise ValueError(f"object kind must be 'spring' or 'string', got {obj.kind!r}")
        pairs = [(a, b) for i, a in enumerate(obj.arms) for b in obj.arms[i + 1:]]
        self.object = obj
        self._edge_names = pairs
        self._edges = np.array([[self.arms[a].index, self.arms[b].index] for a, b in pairs], dtype=np.int64).reshape(-1, 2)
        self._rest = np.array([
            np.linalg.norm(self.tip_world(b) - self.tip_world(a)) if obj.rest_length is None else float(obj.rest_length)
            for a, b in pairs
        ])
        self.tensions = np.zeros(len(pairs))
        self._obj = np.array([obj.stiffness, obj.damping, 1.0 if obj.kind == "string" else 0.0])

    def detach_object(self) -> None:
        self.object = None
        self._edges = np.zeros((0, 2), dtype=np.int64)
        self._edge_names = []
        self._rest = np.zeros(0)
        self.tensions = np.zeros(0)

    @property
    def object_elements(self) -> list[tuple[str, str]]:
        return list(self._edge_names)

    # -- commands -------------------------------------------------------------------------
    def servo_jp(self, name: str, q: np.ndarray, dq: np.ndarray | None = None) -> None:
        a = self.arms[name]
        if self.modes[a.index] != sim_kernel.MODE_POSITION:
            self.integral[a.sl] = 0.0
        self.modes[a.index] = sim_kernel.MODE_POSITION
        self.q_des[a.sl] = q
        self.dq_des[a.sl] = 0.0 if dq is None else dq

    def servo_jf(self, name: str, tau: np.ndarray) -> None:
        a = self.arms[name]
        self.modes[a.index] = sim_kernel.MODE_EFFORT
        self.tau_cmd[a.sl] = tau

    def hold(self, name: str) -> None:
        """Hold the current encoder position under the PID, at rest."""
        a = self.arms[name]
        self.servo_jp(name, self.qm[a.sl].copy())

    def power_off(self, name: str) -> None:
        self.modes[self.arms[name].index] = sim_kernel.MODE_OFF

    def mode(self, name: str) -> str:
        return {sim_kernel.MODE_OFF: "off", sim_kernel.MODE_POSITION: "position",
                sim_kernel.MODE_EFFORT: "effort"}[int(self.modes[self.arms[name].index])]

    # -- physics --------------------------------------------------------------------------
    def step(self) -> None:
        qt = self.G @ self.q
        Mt = pin.crba(self.model, self.data, qt)
        nle = pin.nonLinearEffects(self.model, self.data, qt, self.G @ self.dq)
        sim_kernel.step(self.dt, Mt, nle, self.G, self._state, self._constants, self.modes,
                        self._edges, self._rest, self._obj, self.bases, self.r_offset, self.tensions)
        self._history_pos = (self._history_pos + 1) % len(self._history)
        self._history[self._history_pos] = self.tau_applied
        self.steps += 1
        self.t = self.steps * self.dt
        if self.pace:
            self._wait_wall_clock()

    def _wait_wall_clock(self) -> None:
        if self._wall_start is None:
            self._wall_start = time.perf_counter() - self.t
        lag = self.t - (time.perf_counter() - self._wall_start)
        if lag > 0:
            time.sleep(lag)

    def advance(self, duration: float) -> None:
        for _ in range(int(round(duration / self.dt))):
            self.step()

    # -- measurements ---------------------------------------------------------------------
    def measured_js(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, velocity, effort) as the dVRK reports them: encoder side, noisy, quantised.

        The effort is the commanded one (the dVRK converts motor current), `time_delay` old.
        """
        a = self.arms[name]
        n = a.spec.noise
        q = _quantise(self.qm[a.sl], n.position_quantum)
        dq = self.dqm[a.sl] + a.rng.normal(0.0, 1.0, 3) * n.velocity_noise
        effort = self._history[(self._history_pos - a.delay_steps) % len(self._history), a.columns]
        effort = _quantise(effort + a.rng.normal(0.0, 1.0, 3) * n.effort_noise, n.effort_quantum)
        return q, dq, effort

    def true_state(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        a = self.arms[name]
        return self.q[a.sl].copy(), self.dq[a.sl].copy()

    def setpoint_js(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position setpoint, velocity setpoint, effort applied now)."""
        a = self.arms[name]
        return self.q_des[a.sl].copy(), self.dq_des[a.sl].copy(), self.tau_applied[a.sl].copy()

    def set_state(self, name: str, q: np.ndarray, dq: np.ndarray | None = None) -> None:
        """Place an arm (set-up and tests): joint and motor side together, the PID holding there."""
        a = self.arms[name]
        self.q[a.sl] = q
        self.dq[a.sl] = 0.0 if dq is None else dq
        self.qm[a.sl] = q
        self.dqm[a.sl] = self.dq[a.sl]
        self.q_des[a.sl] = q
        self.integral[a.sl] = 0.0

    def tip_world(self, name: str) -> np.ndarray:
        a = self.arms[name]
        return sim_kernel.tip_and_jacobian(self.q[a.sl].copy(), self.bases[a.index], self.r_offset)[0]

    def tip_pose_world(self, name: str) -> np.ndarray:
        a = self.arms[name]
        return a.spec.base @ K.frames(self.q[a.sl])["tip"]

    def rcm_world(self, name: str) -> np.ndarray:
        return self.arms[name].rcm_world[:3, 3].copy()

    def tension(self, index: int = 0) -> float:
        """True tension of object element `index` (N): what a load cell on it reads."""
        if len(self.tensions) == 0:
            return 0.0
        return float(self.tensions[index])

    def marker_positions(self) -> dict[str, np.ndarray]:
        """True world positions of every marker body's three markers (3x3, m)."""
        poses = self.body_poses()
        return {mb.name: (poses[mb.name][:3, :3] @ mb.offsets.T).T + poses[mb.name][:3, 3]
                for mb in self.marker_bodies}

    def body_poses(self) -> dict[str, np.ndarray]:
        """True world pose (4x4) of every marker body's frame."""
        cache: dict[str, dict[str, np.ndarray]] = {}
        out = {}
        for mb in self.marker_bodies:
            if mb.arm is None:
                out[mb.name] = np.eye(4)
                continue
            if mb.arm not in cache:
                a = self.arms[mb.arm]
                cache[mb.arm] = K.frames(self.q[a.sl])
            out[mb.name] = self.arms[mb.arm].spec.base @ cache[mb.arm][mb.frame]
        return out


def _quantise(x: np.ndarray, quantum: np.ndarray) -> np.ndarray:
    out = np.array(x, dtype=float)
    nz = quantum > 0
    out[nz] = np.round(out[nz] / quantum[nz]) * quantum[nz]
    return out


def world_from_config(cfg, arms: list[str] | None = None, with_object: bool = True,
                      seed: int | None = None) -> SimWorld:
    """The simulated world of a configuration (every arm with driver 'sim')."""
    names = arms or [n for n, a in cfg.arms.items() if a["driver"] == "sim"]
    specs = []
    for name in names:
        a = cfg.arms[name]
        if a["plant_model"]:
            from rig.model.model_file import load_model

            params, effects = load_model(a["plant_model"]).plant()
        else:
            params = PSMParameters()
            effects = HiddenEffects(**{k: (np.array(v) if isinstance(v, list) else v)
                                       for k, v in cfg.effects.get(name, {}).items()})
        specs.append(ArmSpec(name=name, base=cfg.base_matrix(name), params=params, effects=effects,
                             noise=SensorNoise() if a["sensor_noise"] else SensorNoise.off(),
                             effort_limit=np.array(a["effort_limit"]), q0=np.array(a["q0"])))
    obj = None
    o = cfg.object
    if with_object and len(o["arms"]) >= 2 and all(n in names for n in o["arms"]):
        obj = ObjectSpec(arms=tuple(o["arms"]), stiffness=o["stiffness"], damping=o["damping"],
                         rest_length=o["rest_length"], kind=o["kind"])
    return SimWorld(specs, obj, seed=cfg.rig["seed"] if seed is None else seed,
                    dt=1.0 / cfg.rig["rate"], gravity=np.array(cfg.rig["gravity"]), pace=cfg.rig["pace"])
