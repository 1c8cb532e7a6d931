"""Dynamics of PSM joints 1-3 (thesis 4.2) as a Pinocchio open tree with a coupling matrix.

The parallelogram and the counterweights are passive joints that follow the three active
ones linearly: q_tree = G q with a constant 7x3 matrix G. Pinocchio's regressors refuse
mimic joints, so the tree is built open and projected. Virtual work gives the exact
constrained dynamics:

    M(q)  = G^T M_tree(Gq) G + diag(Ia)
    C dq  = G^T C_tree(Gq, G dq) G dq
    g(q)  = G^T g_tree(Gq)
    tau   = G^T Y_tree(Gq, G dq, G ddq) pi_inertial + Y_drive(dq, ddq) pi_drive

Bodies (the thesis' 11 masses m1..m9, mc1, mc2, lumped where rigidly joined):

    yaw_link        m1        turns with q1
    pitch_back      m2        q2 about the pitch axis (link 3, a = 0.150 m)
    pitch_bottom    m3        -q2 relative: keeps its orientation (link 4, a = 0.516 m)
    pitch_end       m4 + m5   +q2 relative (link 5) with the insertion carriage (frame 6)
    tool            m6..m9    moves with q3; the wrist (q4..q6 = 0) lumped in (4.2)
    counterweight_1 mc1       q2 about the pitch axis (frame C1)
    counterweight_2 mc2       slides delta*q3 along frame C2-int

mc1 moves exactly like m2 (the thesis lumps them); it is kept as its own body so the
simulator has a physical counterweight, and the base-parameter reduction merges them.

Standard parameters: per body Pinocchio's `[m, m cx, m cy, m cz, Ixx, Ixy, Iyy, Ixz, Iyz,
Izz]` in the body's joint frame (origin at DH frame i-1, turning with joint i: the
thesis' convention for r_i, 4.2), inertia about that origin; then per joint the drive
`[Fc, Fv, Fo, Ia]` of eq. 4.16: Fc tanh(a dq / 2) + Fv dq + Fo, plus reflected rotor
inertia Ia ddq. Optionally (outside the 82 standard parameters, zero by default) a
Stribeck excess Fst exp(-(dq/vs)^2) tanh(a dq / 2) (thesis 5.6): friction above the
Coulomb level near zero velocity, Fs = Fc + Fst at breakaway.

Nominal values. Friction is the thesis' PSM1 identification (7.5.1 code; its logistic
c/(1+exp(-400 x)) is rewritten as c/2 tanh(200 x) + c/2). Masses and inertias are
estimates for the moving parts of a counterbalanced PSM (yaw structure 1.8 kg, 0.35-0.9 kg
links, 0.35 kg instrument and carriage, counterweights 2.0 and 0.6 kg placed to leave
about a third of the gravity load unbalanced); the reflected rotor inertias are chosen so that
the diagonal of M near home (0.17 kg m^2, 0.20 kg m^2, 0.9 kg) matches what a regression of
shared/data/wpi-psm gives. With the default gravity they produce torques of the order of
that data (about 1-3 N m and N).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from rig.model import psm_kinematics as K

BODY_NAMES = ("yaw_link", "pitch_back", "pitch_bottom", "pitch_end", "tool",
              "counterweight_1", "counterweight_2")
JOINT_NAMES = ("outer_yaw", "outer_pitch", "outer_insertion")
INERTIAL_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
DRIVE_NAMES = ("Fc", "Fv", "Fo", "Ia")

# Tree joint -> active joint coefficient (the coupling matrix G, 7 x 3).
COUPLING = np.array([
    [1.0, 0.0, 0.0],        # yaw_link
    [0.0, 1.0, 0.0],        # pitch_back
    [0.0, -1.0, 0.0],       # pitch_bottom
    [0.0, 1.0, 0.0],        # pitch_end
    [0.0, 0.0, 1.0],        # tool (insertion)
    [0.0, 1.0, 0.0],        # counterweight_1
    [0.0, 0.0, K.DELTA_C2],  # counterweight_2
])

FRICTION_SLOPE = 400.0  # a of eq. 4.14 (s/rad), the thesis' controller value

GRAVITY = np.array([0.0, 0.0, -9.81])  # in PSM frame 0 (z0 up: the tool hangs at q = 0)


def _rod(mass: float, length: float, axis: int, radius: float = 0.02) -> np.ndarray:
    """Inertia about the centre of mass of a rod along `axis` (kg m^2)."""
    transverse = mass * (length ** 2 / 12.0 + radius ** 2 / 4.0)
    I = np.full(3, transverse)
    I[axis] = mass * radius ** 2 / 2.0
    return np.diag(I)


@dataclass(frozen=True)
class Body:
    """A rigid body in its joint frame: mass (kg), centre of mass (m), inertia about it."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray

    def dynamic_parameters(self) -> np.ndarray:
        return pin.Inertia(self.mass, np.asarray(self.com, float), np.asarray(self.inertia, float)).toDynamicParameters()

    @staticmethod
    def from_dynamic_parameters(p: np.ndarray) -> "Body":
        inertia = pin.Inertia.FromDynamicParameters(np.asarray(p, dtype=float))
        return Body(float(inertia.mass), np.array(inertia.lever), np.array(inertia.inertia))


def nominal_bodies() -> dict[str, Body]:
    return {
        # x of the yaw joint frame points up at q1 = 0, z along the yaw axis (the RCM is at -z).
        "yaw_link": Body(1.8, np.array([-0.026, -0.008, -0.20]), _rod(1.8, 0.45, 2, 0.06)),
        # x along each parallelogram link, z along the pitch axis.
        "pitch_back": Body(0.35, np.array([0.075, 0.0, 0.02]), _rod(0.35, K.A3, 0)),
        "pitch_bottom": Body(0.45, np.array([0.258, 0.0, 0.03]), _rod(0.45, K.A4, 0)),
        "pitch_end": Body(0.9, np.array([0.20, -0.03, 0.0]), _rod(0.9, K.A5, 0, 0.04)),
        # z along the instrument shaft, origin at the wrist: the housing sits 0.3 m behind it.
        "tool": Body(0.35, np.array([0.0, 0.0, -0.30]), _rod(0.35, 0.40, 2, 0.02)),
        # below and behind the pitch axis, balancing the parallelogram.
        "counterweight_1": Body(2.0, np.array([-0.081, -0.005, 0.0]), _rod(1.3, 0.08, 2, 0.04)),
        "counterweight_2": Body(0.6, np.array([0.115, 0.0, -0.165]), _rod(0.6, 0.05, 2, 0.02)),
    }


@dataclass(frozen=True)
class DriveParameters:
    """Per active joint: Coulomb Fc, viscous Fv, offset Fo (eq. 4.16), rotor inertia Ia."""

    Fc: np.ndarray = field(default_factory=lambda: np.array([0.0545, 0.0816, 0.5345]))
    Fv: np.ndarray = field(default_factory=lambda: np.array([0.0954, 0.1633, 0.7663]))
    Fo: np.ndarray = field(default_factory=lambda: np.array([0.3296, 0.2753, 0.1500]))
    Ia: np.ndarray = field(default_factory=lambda: np.array([0.06, 0.07, 0.15]))
    slope: float = FRICTION_SLOPE
    #: Stribeck excess over Coulomb at rest (N m, N m, N) and Stribeck velocity (rad/s, m/s);
    #: not among the standard parameters (see the module docstring).
    Fst: np.ndarray = field(default_factory=lambda: np.zeros(3))
    vs: np.ndarray = field(default_factory=lambda: np.full(3, 0.01))

    def vector(self) -> np.ndarray:
        return np.column_stack([self.Fc, self.Fv, self.Fo, self.Ia]).ravel()

    @staticmethod
    def from_vector(v: np.ndarray, slope: float = FRICTION_SLOPE) -> "DriveParameters":
        v = np.asarray(v, dtype=float).reshape(3, 4)
        return DriveParameters(v[:, 0].copy(), v[:, 1].copy(), v[:, 2].copy(), v[:, 3].copy(), slope)


@dataclass(frozen=True)
class PSMParameters:
    bodies: dict[str, Body] = field(default_factory=nominal_bodies)
    drive: DriveParameters = field(default_factory=DriveParameters)

    def standard_vector(self) -> np.ndarray:
        inertial = np.concatenate([self.bodies[b].dynamic_parameters() for b in BODY_NAMES])
        return np.concatenate([inertial, self.drive.vector()])

    @staticmethod
    def from_standard_vector(pi: np.ndarray, slope: float = FRICTION_SLOPE) -> "PSMParameters":
        pi = np.asarray(pi, dtype=float)
        n = 10 * len(BODY_NAMES)
        bodies = {b: Body.from_dynamic_parameters(pi[10 * i:10 * i + 10]) for i, b in enumerate(BODY_NAMES)}
        return PSMParameters(bodies, DriveParameters.from_vector(pi[n:n + 12], slope))

    def with_payload(self, mass: float, com_on_tool: np.ndarray = np.zeros(3)) -> "PSMParameters":
        """Add a point mass rigidly on the tool body (kg, m in the tool joint frame)."""
        tool = self.bodies["tool"]
        added = pin.Inertia(tool.mass, tool.com, tool.inertia) + pin.Inertia(mass, np.asarray(com_on_tool, float), np.zeros((3, 3)))
        bodies = dict(self.bodies)
        bodies["tool"] = Body(float(added.mass), np.array(added.lever), np.array(added.inertia))
        return replace(self, bodies=bodies)


def standard_parameter_names() -> list[str]:
    names = [f"{b}.{p}" for b in BODY_NAMES for p in INERTIAL_NAMES]
    names += [f"joint{j + 1}.{p}" for j in range(3) for p in DRIVE_NAMES]
    return names


def _se3(T: np.ndarray) -> pin.SE3:
    return pin.SE3(np.asarray(T[:3, :3]), np.asarray(T[:3, 3]))


def _rz(theta: float) -> np.ndarray:
    return K.dh(0.0, 0.0, 0.0, theta)


def add_psm_tree(model: pin.Model, params: PSMParameters, base: np.ndarray = np.eye(4),
                 prefix: str = "") -> list[int]:
    """Append one PSM's open tree to `model` under the universe, at `base` (frame 0 in world).

    Returns the Pinocchio joint ids in the order of BODY_NAMES (the rows of COUPLING).
    """
    S2 = K.dh(0.0, -np.pi / 2, K.D2, 0.0)
    S3 = K.dh(K.A3, 0.0, 0.0, 0.0)
    S4 = K.dh(K.A4, 0.0, 0.0, 0.0)
    S5 = K.dh(K.A5, 0.0, 0.0, 0.0)
    to_insertion = S5 @ K.dh(K.A6, np.pi / 2, 0.0, K.THETA6) @ _rz(np.pi / 2) @ K.dh(0, 0, K.D7_OFFSET, 0)
    c2_int = K.dh(0.0, -np.pi / 2, 0.0, -np.pi / 2 - K.BETA)

    def add(parent: int, joint, placement: np.ndarray, body: str) -> int:
        jid = model.addJoint(parent, joint, _se3(placement), prefix + body)
        b = params.bodies[body]
        model.appendBodyToJoint(jid, pin.Inertia(b.mass, np.asarray(b.com, float), np.asarray(b.inertia, float)), pin.SE3.Identity())
        return jid

    yaw = add(0, pin.JointModelRZ(), base @ K.T01 @ _rz(-np.pi / 2), "yaw_link")
    back = add(yaw, pin.JointModelRZ(), S2 @ _rz(-K.BETA), "pitch_back")
    bottom = add(back, pin.JointModelRZ(), S3 @ _rz(K.BETA + np.pi / 2), "pitch_bottom")
    end = add(bottom, pin.JointModelRZ(), S4 @ _rz(-K.BETA), "pitch_end")
    tool = add(end, pin.JointModelPZ(), to_insertion, "tool")
    cw1 = add(yaw, pin.JointModelRZ(), S2, "counterweight_1")
    cw2 = add(cw1, pin.JointModelPZ(), c2_int, "counterweight_2")
    model.addFrame(pin.Frame(prefix + "tip", tool, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    return [yaw, back, bottom, end, tool, cw1, cw2]


class PSMDynamics:
    """M, C dq, g, friction, Jacobian and the standard-parameter regressor of joints 1-3.

    `gravity` is the gravity vector in frame 0 (m/s^2); a PSM on a set-up joint is tilted,
    so identification on real data may set it.
    """

    n_joints = 3
    body_names = BODY_NAMES
    joint_names = JOINT_NAMES

    def __init__(self, params: PSMParameters | None = None, gravity: np.ndarray = GRAVITY):
        self.params = params or PSMParameters()
        self.model = pin.Model()
        self.joint_ids = add_psm_tree(self.model, self.params)
        self.model.gravity = pin.Motion(np.asarray(gravity, float), np.zeros(3))
        self.gravity = np.asarray(gravity, float)
        self.data = self.model.createData()
        self.tip_frame = self.model.getFrameId("tip")
        self.G = COUPLING.copy()
        self.GT = self.G.T.copy()
        d = self.params.drive
        self.Fc, self.Fv, self.Fo, self.Ia = d.Fc.copy(), d.Fv.copy(), d.Fo.copy(), d.Ia.copy()
        self.Fst, self.vs = np.asarray(d.Fst, float).copy(), np.asarray(d.vs, float).copy()
        if np.any(self.vs <= 0):
            raise ValueError(f"Stribeck velocities must be > 0, got {self.vs}")
        self.slope = d.slope
        self.n_params = 10 * len(BODY_NAMES) + 4 * 3
        self._lower = np.tril_indices(self.model.nv, -1)
        self._Ia_diag = np.diag(self.Ia)

    # -- parameters -------------------------------------------------------------------
    def standard_params(self) -> np.ndarray:
        return self.params.standard_vector()

    @staticmethod
    def param_names() -> list[str]:
        return standard_parameter_names()

    # -- dynamics ---------------------------------------------------------------------
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        Mt = pin.crba(self.model, self.data, self.G @ q)
        Mt[self._lower] = Mt.T[self._lower]  # crba fills the upper triangle only
        return self.GT @ Mt @ self.G + self._Ia_diag

    def coriolis(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """C(q, dq) dq (N m, N)."""
        qt, vt = self.G @ q, self.G @ dq
        return self.GT @ (pin.nonLinearEffects(self.model, self.data, qt, vt)
                          - pin.computeGeneralizedGravity(self.model, self.data, qt))

    def coriolis_matrix(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        Ct = pin.computeCoriolisMatrix(self.model, self.data, self.G @ q, self.G @ dq)
        return self.GT @ Ct @ self.G

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        return self.GT @ pin.computeGeneralizedGravity(self.model, self.data, self.G @ q)

    def bias(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """C(q, dq) dq + g(q) in one pass."""
        return self.GT @ pin.nonLinearEffects(self.model, self.data, self.G @ q, self.G @ dq)

    def friction(self, dq: np.ndarray) -> np.ndarray:
        """Eq. 4.16 with the sigmoid of 4.14: Fc tanh(a dq / 2) + Fv dq + Fo, plus the
        Stribeck excess Fst exp(-(dq/vs)^2) tanh(a dq / 2) (zero unless identified)."""
        return ((self.Fc + self.Fst * np.exp(-(dq / self.vs) ** 2)) * np.tanh(0.5 * self.slope * dq)
                + self.Fv * dq + self.Fo)

    def stribeck_columns(self, DQ: np.ndarray, vs) -> np.ndarray:
        """Stacked (3N, 3) columns of the Stribeck excess: row 3k+j, column j is
        exp(-(dq_kj/vs_j)^2) tanh(a dq_kj / 2), so that their product with Fst (3,) is the
        term of :meth:`friction` (``vs`` (3,) in rad/s, rad/s, m/s)."""
        DQ = np.atleast_2d(np.asarray(DQ, float))
        vs = np.broadcast_to(np.asarray(vs, float), (3,))
        S = np.exp(-(DQ / vs) ** 2) * np.tanh(0.5 * self.slope * DQ)
        out = np.zeros((DQ.shape[0], 3, 3))
        for j in range(3):
            out[:, j, j] = S[:, j]
        return out.reshape(-1, 3)

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, friction: bool = True) -> np.ndarray:
        """Joint efforts for a motion: rigid body + rotor inertia (+ friction), N m and N."""
        tau = self.GT @ pin.rnea(self.model, self.data, self.G @ q, self.G @ dq, self.G @ ddq) + self.Ia * ddq
        return tau + self.friction(dq) if friction else tau

    def forward_dynamics(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray, friction: bool = True) -> np.ndarray:
        rhs = tau - self.bias(q, dq)
        if friction:
            rhs = rhs - self.friction(dq)
        return np.linalg.solve(self.mass_matrix(q), rhs)

    def energy(self, q: np.ndarray, dq: np.ndarray) -> float:
        """Kinetic (links and rotors) plus potential energy (J)."""
        qt, vt = self.G @ q, self.G @ dq
        kinetic = pin.computeKineticEnergy(self.model, self.data, qt, vt) + 0.5 * float(self.Ia @ (dq * dq))
        return kinetic + pin.computePotentialEnergy(self.model, self.data, qt)

    # -- kinematics through Pinocchio ---------------------------------------------------
    def tip_jacobian(self, q: np.ndarray) -> np.ndarray:
        """6x3 geometric Jacobian of the tool tip in frame 0 (linear; angular)."""
        Jt = pin.computeFrameJacobian(self.model, self.data, self.G @ q, self.tip_frame,
                                      pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return Jt @ self.G

    def tip_placement(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, self.G @ q)
        return self.data.oMf[self.tip_frame].homogeneous

    # -- regressor --------------------------------------------------------------------
    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Y (3 x 82) with tau = Y pi for the standard parameters (names: param_names())."""
        Yt = pin.computeJointTorqueRegressor(self.model, self.data, self.G @ q, self.G @ dq, self.G @ ddq)
        Y = np.empty((3, self.n_params))
        Y[:, :70] = self.GT @ Yt
        Y[:, 70:] = self._drive_columns(dq, ddq)
        return Y

    def _drive_columns(self, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        cols = np.zeros((3, 12))
        for j in range(3):
            cols[j, 4 * j:4 * j + 4] = (np.tanh(0.5 * self.slope * dq[j]), dq[j], 1.0, ddq[j])
        return cols

    def regressor_batch(self, Q: np.ndarray, DQ: np.ndarray, DDQ: np.ndarray) -> np.ndarray:
        """Stacked regressor (3N x 82), rows 3k..3k+2 for sample k."""
        n = len(Q)
        W = np.empty((3 * n, self.n_params))
        for k in range(n):
            W[3 * k:3 * k + 3] = self.regressor(Q[k], DQ[k], DDQ[k])
        return W
