"""The standard dynamic-parameter layout shared by the PSM model and the fits.

Layout of the standard parameter vector ``pi`` (length ``10 * n_bodies + 4 * n_joints``):

* for each rigid body, in Pinocchio's order (what ``pinocchio.Inertia.toDynamicParameters``
  gives and what ``pinocchio.computeJointTorqueRegressor`` multiplies), inertia about the
  body's joint-frame origin::

      [m, m*cx, m*cy, m*cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]      (kg, kg m, kg m^2)

* then for each actuated joint, the drive parameters::

      [Fc, Fv, Fo, Ia]

  Coulomb level (N m or N) multiplying the smooth sign ``tanh(a*dq/2)``; viscous
  coefficient (N m s/rad or N s/m); constant offset (N m or N); reflected rotor inertia
  (kg m^2 or kg) multiplying ``ddq_j``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Names of the 10 inertial parameters of one body, Pinocchio order.
BODY_PARAM_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
#: Names of the 4 drive parameters of one actuated joint.
DRIVE_PARAM_NAMES = ("Fc", "Fv", "Fo", "Ia")

#: Default steepness of the smooth Coulomb sign tanh(a*dq/2), in s/rad (or s/m).
DEFAULT_SIGN_STEEPNESS = 400.0


@dataclass(frozen=True)
class ParamLayout:
    """Where each standard parameter sits in ``pi``; names like ``"tool.m"``, ``"joint3.Fc"``."""

    n_bodies: int
    n_joints: int
    body_names: tuple[str, ...] = field(default=())
    joint_names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        if not self.body_names:
            object.__setattr__(self, "body_names", tuple(f"body{i + 1}" for i in range(self.n_bodies)))
        if not self.joint_names:
            object.__setattr__(self, "joint_names", tuple(f"joint{j + 1}" for j in range(self.n_joints)))
        object.__setattr__(self, "body_names", tuple(self.body_names))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        if len(self.body_names) != self.n_bodies:
            raise ValueError(f"ParamLayout: {len(self.body_names)} body names for {self.n_bodies} bodies")
        if len(self.joint_names) != self.n_joints:
            raise ValueError(f"ParamLayout: {len(self.joint_names)} joint names for {self.n_joints} joints")
        names = list(self.body_names) + list(self.joint_names)
        if len(set(names)) != len(names):
            raise ValueError(f"ParamLayout: body and joint names must be unique, got {names}")

    @classmethod
    def of(cls, layout) -> "ParamLayout":
        """Accept a layout-like object (``n_bodies``, ``n_joints``, ``body_names``,
        ``joint_names``), or a model carrying one as ``param_layout`` or just the names."""
        if isinstance(layout, cls):
            return layout
        if hasattr(layout, "param_layout"):
            return cls.of(layout.param_layout)
        bodies, joints = tuple(layout.body_names), tuple(layout.joint_names)
        return cls(int(getattr(layout, "n_bodies", len(bodies))), int(getattr(layout, "n_joints", len(joints))),
                   bodies, joints)

    @property
    def n_params(self) -> int:
        return 10 * self.n_bodies + 4 * self.n_joints

    @property
    def n_inertial(self) -> int:
        return 10 * self.n_bodies

    def body_slice(self, b: int) -> slice:
        """Columns of body ``b`` (0-based)."""
        return slice(10 * b, 10 * b + 10)

    def mass_index(self, b: int) -> int:
        return 10 * b

    def drive_index(self, j: int, name: str) -> int:
        """Index of drive parameter ``name`` ("Fc", "Fv", "Fo", "Ia") of joint ``j`` (0-based)."""
        return self.n_inertial + 4 * j + DRIVE_PARAM_NAMES.index(name)

    def drive_indices(self, name: str) -> np.ndarray:
        return np.array([self.drive_index(j, name) for j in range(self.n_joints)], dtype=int)

    @property
    def mass_indices(self) -> np.ndarray:
        return np.arange(self.n_bodies, dtype=int) * 10

    def names(self) -> list[str]:
        """One name per standard parameter, e.g. ``["link1.m", ..., "joint3.Ia"]``."""
        out = [f"{b}.{p}" for b in self.body_names for p in BODY_PARAM_NAMES]
        out += [f"{j}.{p}" for j in self.joint_names for p in DRIVE_PARAM_NAMES]
        return out

    def index(self, name: str) -> int:
        """Index of a parameter from its name, e.g. ``"tool.Ixx"``."""
        try:
            return self.names().index(name)
        except ValueError:
            raise KeyError(f"no standard parameter named {name!r}") from None


def drive_regressor(dq: np.ndarray, ddq: np.ndarray,
                    sign_steepness: float = DEFAULT_SIGN_STEEPNESS) -> np.ndarray:
    """Drive columns for one sample: (n, 4n) with row j = [tanh(a dq_j/2), dq_j, 1, ddq_j] in block j."""
    dq = np.asarray(dq, dtype=float)
    ddq = np.asarray(ddq, dtype=float)
    n = dq.shape[0]
    Y = np.zeros((n, 4 * n))
    idx = np.arange(n)
    Y[idx, 4 * idx] = np.tanh(0.5 * sign_steepness * dq)
    Y[idx, 4 * idx + 1] = dq
    Y[idx, 4 * idx + 2] = 1.0
    Y[idx, 4 * idx + 3] = ddq
    return Y


def pseudo_inertia(body_params: np.ndarray) -> np.ndarray:
    """4x4 pseudo-inertia J = [[Sigma, h], [h^T, m]] of one body (Wensing et al. 2017).

    ``body_params`` is ``[m, hx, hy, hz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` with the rotational
    inertia about the frame origin; Sigma = tr(I)/2 * 1 - I is the second moment of mass.
    J >= 0 is exactly the set of parameters some non-negative mass distribution realises.
    """
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(body_params, dtype=float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J = np.empty((4, 4))
    J[:3, :3] = sigma
    J[:3, 3] = J[3, :3] = (hx, hy, hz)
    J[3, 3] = m
    return J
