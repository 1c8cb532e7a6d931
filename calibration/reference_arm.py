"""A known-truth 3-DOF arm (yaw, pitch, insertion) for testing and benchmarking the fits.

It is built the same way as the PSM model (a Pinocchio open tree whose passive joints follow
the three actuated ones through a constant coupling matrix G, q_tree = G q), so the fits
meet the same structure of base parameters: counterweights moving with -q2 and -q3/2, a
parallelogram-like pair of links, and a tool body rigidly fixed to the insertion stage
(a tree joint held at zero). Its true parameters are drawn from a seed and are physically
consistent; it computes torques two independent ways (regressor and RNEA) so tests can check
one against the other.

It is not a model of the PSM: use ``rig.model.psm_dynamics.PSMDynamics`` for that.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calibration.layout import DEFAULT_SIGN_STEEPNESS, ParamLayout, drive_regressor

# Table 4.2, joints 1-3 (rad, rad, m; rad/s, rad/s, m/s). The insertion range is taken as
# [0, 0.24] m, since the stage cannot go behind the remote centre.
Q_MIN = np.array([-1.58, -0.93, 0.0])
Q_MAX = np.array([1.58, 0.93, 0.24])
DQ_MAX = np.array([2.0, 2.0, 0.4])


class ReferenceArm:
    """Yaw-pitch-insertion arm with counterweights; see the module docstring.

    ``regressor(q, dq, ddq) -> (3, P)`` and ``regressor_batch(Q, DQ, DDQ) -> (3N, P)``
    (sample-major) multiply the standard parameters of ``param_layout``.
    """

    # In tree order. Joints are added depth first: Pinocchio's CRBA assumes each joint's
    # subtree occupies a contiguous range of velocity indices (RNEA and the regressor do not),
    # and silently returns a wrong M(q) otherwise.
    body_names = ("link1", "link2", "link3", "tool", "parallel_link", "parallel_top",
                  "counterweight1", "counterweight2")
    joint_names = ("joint1", "joint2", "joint3")

    def __init__(self, seed: int = 0, sign_steepness: float = DEFAULT_SIGN_STEEPNESS,
                 point_mass_bodies: tuple[str, ...] = ()):
        self.sign_steepness = float(sign_steepness)
        self.model = self._build_tree()
        self.data = self.model.createData()
        # Rows: tree joints (pinocchio order); columns: actuated joints.
        self.G = np.array([
            [1.0, 0.0, 0.0],    # yaw
            [0.0, 1.0, 0.0],    # pitch
            [0.0, 0.0, 1.0],    # insertion
            [0.0, 0.0, 0.0],    # tool, rigidly fixed to the insertion stage
            [0.0, -1.0, 0.0],   # parallelogram link keeps its orientation
            [0.0, 1.0, 0.0],    # top link of the parallelogram
            [0.0, -1.0, 0.0],   # counterweight arm turns against the pitch
            [0.0, 0.0, -0.5],   # counterweight slides back at half the insertion
        ])
        self.param_layout = ParamLayout(len(self.body_names), 3, self.body_names, self.joint_names)
        self.q_min, self.q_max, self.dq_max = Q_MIN.copy(), Q_MAX.copy(), DQ_MAX.copy()
        rng = np.random.default_rng(seed)
        self._true = self._draw_params(rng, point_mass_bodies)
        self._nominal = self._perturb(rng, self._true)

    # -- construction ------------------------------------------------------------------------
    def _build_tree(self) -> pin.Model:
        m = pin.Model()
        T = lambda x, y, z: pin.SE3(np.eye(3), np.array([x, y, z]))  # noqa: E731
        j1 = m.addJoint(0, pin.JointModelRZ(), T(0, 0, 0), "yaw")
        j2 = m.addJoint(j1, pin.JointModelRY(), T(0, 0, 0.15), "pitch")
        j3 = m.addJoint(j2, pin.JointModelPX(), T(0.30, 0, 0), "insertion")
        m.addJoint(j3, pin.JointModelRZ(), T(0.10, 0, 0), "tool_fixed")
        j5 = m.addJoint(j2, pin.JointModelRY(), T(0.10, 0, 0), "parallel")
        m.addJoint(j5, pin.JointModelRY(), T(0, 0, 0.12), "parallel_top")
        j7 = m.addJoint(j1, pin.JointModelRY(), T(0, 0, 0.15), "cw_arm")
        m.addJoint(j7, pin.JointModelPX(), T(-0.10, 0, 0), "cw_slide")
        # Placeholder inertias: every computation here takes parameters explicitly.
        for j in range(1, m.njoints):
            m.appendBodyToJoint(j, pin.Inertia(1.0, np.zeros(3), np.eye(3) * 1e-2), pin.SE3.Identity())
        return m

    def _draw_params(self, rng, point_mass_bodies) -> np.ndarray:
        com_centres = {"link1": (0, 0, 0.07), "link2": (0.15, 0, 0), "link3": (0.05, 0, 0),
                       "tool": (0.03, 0, 0), "counterweight1": (-0.05, 0, 0),
                       "counterweight2": (-0.05, 0, 0), "parallel_link": (0, 0, 0.06),
                       "parallel_top": (0.05, 0, 0)}
        out = []
        for name in self.body_names:
            mass = rng.uniform(0.3, 2.0)
            com = np.array(com_centres[name]) + rng.uniform(-0.02, 0.02, 3)
            if name in point_mass_bodies:
                # On the boundary of physical consistency: noise pushes LS fits out of it.
                inertia_c = np.eye(3) * 1e-9
            else:
                dims = rng.uniform(0.02, 0.15, 3)
                inertia_c = mass / 12.0 * np.diag([dims[1] ** 2 + dims[2] ** 2,
                                                   dims[0] ** 2 + dims[2] ** 2,
                                                   dims[0] ** 2 + dims[1] ** 2])
                R = pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3))
                inertia_c = R @ inertia_c @ R.T
            out.append(pin.Inertia(mass, com, inertia_c).toDynamicParameters())
        drives = []
        for fc, fv, ia in ((0.15, 0.05, 0.01), (0.2, 0.08, 0.015), (0.8, 2.0, 0.2)):
            drives += [fc * rng.uniform(0.8, 1.2), fv * rng.uniform(0.8, 1.2),
                       rng.uniform(-0.05, 0.05), ia * rng.uniform(0.8, 1.2)]
        return np.concatenate(out + [np.array(drives)])

    def _perturb(self, rng, pi) -> np.ndarray:
        """A nominal set: each body's mass, centre of mass and inertia off by ~20 %."""
        out = []
        for b in range(self.param_layout.n_bodies):
            inert = pin.Inertia.FromDynamicParameters(pi[10 * b:10 * b + 10])
            out.append(pin.Inertia(inert.mass * rng.uniform(0.8, 1.2),
                                   inert.lever + rng.uniform(-0.01, 0.01, 3),
                                   inert.inertia * rng.uniform(0.8, 1.2) + np.eye(3) * 1e-6
                                   ).toDynamicParameters())
        drives = pi[10 * self.param_layout.n_bodies:] * rng.uniform(0.7, 1.3, 12)
        return np.concatenate(out + [drives])

    # -- the interface the fits use ----------------------------------------------------------
    def true_params(self) -> np.ndarray:
        return self._true.copy()

    def nominal_params(self) -> np.ndarray:
        return self._nominal.copy()

    def regressor(self, q, dq, ddq) -> np.ndarray:
        """(3, P): tau = regressor @ pi, in N m, N m, N."""
        G = self.G
        Yt = pin.computeJointTorqueRegressor(self.model, self.data, G @ q, G @ dq, G @ ddq)
        return np.hstack([G.T @ Yt, drive_regressor(dq, ddq, self.sign_steepness)])

    def regressor_batch(self, Q, DQ, DDQ) -> np.ndarray:
        """(3N, P), rows 3k..3k+2 are sample k."""
        Q, DQ, DDQ = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (Q, DQ, DDQ))
        n = Q.shape[0]
        P = self.param_layout.n_params
        out = np.empty((3 * n, P))
        G = self.G
        QT, DQT, DDQT = Q @ G.T, DQ @ G.T, DDQ @ G.T
        nin = self.param_layout.n_inertial
        for k in range(n):
            Yt = pin.computeJointTorqueRegressor(self.model, self.data, QT[k], DQT[k], DDQT[k])
            out[3 * k:3 * k + 3, :nin] = G.T @ Yt
        # Drive columns, vectorised.
        out[:, nin:] = 0.0
        rows = np.arange(n) * 3
        for j in range(3):
            c = nin + 4 * j
            out[rows + j, c] = np.tanh(0.5 * self.sign_steepness * DQ[:, j])
            out[rows + j, c + 1] = DQ[:, j]
            out[rows + j, c + 2] = 1.0
            out[rows + j, c + 3] = DDQ[:, j]
        return out

    # -- independent paths, for checks -------------------------------------------------------
    def _set_inertias(self, pi):
        for b in range(self.param_layout.n_bodies):
            self.model.inertias[b + 1] = pin.Inertia.FromDynamicParameters(np.asarray(pi[10 * b:10 * b + 10]))

    def torque_rnea(self, q, dq, ddq, pi) -> np.ndarray:
        """Joint torques (3,) by RNEA on the tree projected with G^T, plus the drive terms."""
        self._set_inertias(pi)
        G = self.G
        tau = G.T @ pin.rnea(self.model, self.data, G @ q, G @ dq, G @ ddq)
        return tau + drive_regressor(dq, ddq, self.sign_steepness) @ pi[self.param_layout.n_inertial:]

    def mass_matrix(self, q, pi) -> np.ndarray:
        """M(q) (3, 3) by CRBA on the tree, projected, plus reflected rotor inertias."""
        self._set_inertias(pi)
        G = self.G
        M = pin.crba(self.model, self.data, G @ q)
        M = np.triu(M) + np.triu(M, 1).T
        Ia = pi[self.param_layout.drive_indices("Ia")]
        return G.T @ M @ G + np.diag(Ia)
