"""Kinematics of the dVRK Patient Side Manipulator after thesis Table 4.3.

Frames follow the conventional Denavit-Hartenberg table of the thesis: frames 0-11 along
the arm, plus the counterweight frames C1, C2-int and C2. Two numbers the table leaves
open are solved here rather than guessed:

* The literal table cannot hold a remote centre of motion for any beta. With frame 6 at
  theta = -pi/2 the insertion axis is perpendicular to link 3 and passes the point the
  arm pivots about at a fixed distance a3 + a6 = 0.107 m, whatever beta is (the rotating
  offset and the axis turn together). The completion used here keeps every link length
  and the beta pattern of frames 3-5 and sets frame 6 to theta = beta - pi. Two conditions
  then fix beta: the insertion axis passes through the yaw axis (exact RCM for all q1, q2)
  and, as on the dVRK, it is perpendicular to the yaw axis at q2 = 0. They give
  a3 sin(beta) - a5 cos(beta) = -a6, solved in closed form below (beta ~ 1.224 rad).
* The table's insertion d = q3 starts at frame 6, 0.32 m behind the RCM. The dVRK reports
  the wrist at (q3 - l_RCC + l_tool) past the RCM (l_RCC = 0.4318 m, l_tool = 0.4162 m for
  the large needle driver), so frame 7 gets a constant offset that makes the two agree.

The RCM frame is the dVRK's PSM kinematic base frame: origin at the RCM, -z along the tool
at q = 0, yaw about -y, pitch about -x. `RCM_FRAME` maps it to frame 0. What this module
calls the tip is the shaft end (the wrist-pitch axis point), where the simulated object
is attached; the dVRK's `measured_cp` is the tool tip of its whole PSM with a tool, 9.1 mm
further along the shaft for the large needle driver and turned 90 deg about it:
`rig.model.psm_arm_kinematics` (forward(q) = tip_pose_rcm(q[:3]) @ RIG_TIP_TO_TOOL_TIP at wrist 0).

Units: m and rad. Joint 3 (insertion) is in m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Thesis Table 4.3 link lengths (m).
D1 = 0.1524
D2 = 0.0296
A3 = 0.150
A4 = 0.516
A5 = 0.2881
A6 = -0.0430
A9 = 0.0091
A10 = 0.0102

# dVRK large needle driver: RCM-to-base insertion offset and tool length (m).
L_RCC = 0.4318
L_TOOL = 0.4162

# Counterweight 2 travels delta * q3 (thesis 4.1.2, "a measured constant"). The dVRK
# insertion counterweight is cabled to the carriage; 0.8 is this project's choice, with
# the C2-int axis of Table 4.3 it lifts the counterweight as the tool goes in.
DELTA_C2 = 0.8

# Thesis Table 4.2: joint limits (rad, m for joint 3) and maximum velocities.
# The table lists joint 3 as +/-0.24; the dVRK's insertion never goes behind the RCM
# cannula (q3 >= 0), which the real data in shared/data/wpi-psm respects (0.09-0.24 m).
Q_MIN = np.array([-1.58, -0.93, 0.0])
Q_MAX = np.array([1.58, 0.93, 0.24])
DQ_MAX = np.array([2.0, 2.0, 0.4])


def _solve_beta() -> float:
    # a3 sin(b) - a5 cos(b) = -a6  ->  R sin(b - phi) = -a6 with R, phi below.
    r = np.hypot(A3, A5)
    phi = np.arctan2(A5, A3)
    return float(phi + np.arcsin(-A6 / r))


BETA = _solve_beta()
THETA6 = BETA - np.pi


def dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """Conventional DH transform Rz(theta) Tz(d) Tx(a) Rx(alpha) as a 4x4 matrix."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array([
        [ct, -st * ca, st * sa, a * ct],
        [st, ct * ca, -ct * sa, a * st],
        [0.0, sa, ca, d],
        [0.0, 0.0, 0.0, 1.0],
    ])


def _rcm_offset() -> tuple[float, np.ndarray]:
    """Distance from frame 6 to the RCM along the insertion axis, and the RCM in frame 2."""
    # In frame 2's plane the parallelogram turns about the origin by q2; at q2 = 0:
    p6 = (A3 * np.array([np.cos(-BETA), np.sin(-BETA)])
          + A4 * np.array([0.0, 1.0])
          + A5 * np.array([np.cos(np.pi / 2 - BETA), np.sin(np.pi / 2 - BETA)])
          + A6 * np.array([np.cos(-np.pi / 2), np.sin(-np.pi / 2)]))
    rcm = np.array([0.0, A4])
    return float(np.linalg.norm(p6 - rcm)), np.array([0.0, A4, 0.0])


RCM_DISTANCE_FROM_FRAME6, RCM_IN_FRAME2 = _rcm_offset()
# Frame 7's insertion offset: wrist at (q3 - L_RCC + L_TOOL) past the RCM.
D7_OFFSET = RCM_DISTANCE_FROM_FRAME6 + L_TOOL - L_RCC

T01 = dh(0.0, -np.pi / 2, D1, np.pi / 2)


def frames(q: np.ndarray, wrist: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every frame of Table 4.3 in frame 0 (4x4), for joints q = (q1, q2, q3).

    `wrist` = (q4, q5, q6) for frames 8-11 (default zero, the tool lumped as in 4.2).
    "tip" is frame 7, the wrist point the dVRK reports as the tool tip of joints 1-3.
    """
    q1, q2, q3 = float(q[0]), float(q[1]), float(q[2])
    q4, q5, q6 = (0.0, 0.0, 0.0) if wrist is None else (float(w) for w in wrist)
    T = {"0": np.eye(4), "1": T01}
    T["2"] = T["1"] @ dh(0.0, -np.pi / 2, D2, -np.pi / 2 + q1)
    T["3"] = T["2"] @ dh(A3, 0.0, 0.0, -BETA + q2)
    T["4"] = T["3"] @ dh(A4, 0.0, 0.0, BETA + np.pi / 2 - q2)
    T["5"] = T["4"] @ dh(A5, 0.0, 0.0, -BETA + q2)
    T["6"] = T["5"] @ dh(A6, np.pi / 2, 0.0, THETA6)
    T["7"] = T["6"] @ dh(0.0, 0.0, q3 + D7_OFFSET, np.pi / 2)
    T["8"] = T["7"] @ dh(0.0, np.pi / 2, 0.0, np.pi / 2 + q4)
    T["9"] = T["8"] @ dh(A9, -np.pi / 2, 0.0, np.pi / 2 + q5)
    T["10"] = T["9"] @ dh(A10, 0.0, 0.0, q6)
    T["11"] = T["10"] @ dh(0.0, -np.pi / 2, 0.0, -np.pi / 2)
    T["C1"] = T["2"] @ dh(0.0, 0.0, 0.0, q2)
    T["C2-int"] = T["2"] @ dh(0.0, -np.pi / 2, 0.0, -np.pi / 2 - BETA + q2)
    T["C2"] = T["C2-int"] @ dh(0.0, 0.0, DELTA_C2 * q3, 0.0)
    T["tip"] = T["7"]
    return T


def _rcm_frame() -> np.ndarray:
    """The dVRK RCM frame in frame 0 (constant)."""
    T = frames(np.zeros(3))
    z1 = T["1"][:3, 2]
    z2 = T["2"][:3, 2]
    tool = T["6"][:3, 2]  # insertion direction at q = 0
    R = np.column_stack([-z2, -z1, -tool])
    F = np.eye(4)
    F[:3, :3] = R
    F[:3, 3] = (T["2"] @ np.append(RCM_IN_FRAME2, 1.0))[:3]
    return F


RCM_FRAME = _rcm_frame()
RCM_FRAME_INV = np.linalg.inv(RCM_FRAME)


def tip_in_rcm(q: np.ndarray) -> np.ndarray:
    """Tool-tip position in the RCM frame (m), closed form of the dVRK's yaw/pitch/insertion."""
    q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2]
    r = q3 - L_RCC + L_TOOL
    c1, s1, c2, s2 = np.cos(q1), np.sin(q1), np.cos(q2), np.sin(q2)
    return np.stack([c2 * s1 * r, -s2 * r, -c1 * c2 * r], axis=-1)


def tip_jacobian_rcm(q: np.ndarray) -> np.ndarray:
    """d(tip_in_rcm)/dq, shape (..., 3, 3)."""
    q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2]
    r = q3 - L_RCC + L_TOOL
    c1, s1, c2, s2 = np.cos(q1), np.sin(q1), np.cos(q2), np.sin(q2)
    J = np.empty(np.shape(q1) + (3, 3))
    J[..., 0, 0] = c2 * c1 * r
    J[..., 0, 1] = -s2 * s1 * r
    J[..., 0, 2] = c2 * s1
    J[..., 1, 0] = 0.0
    J[..., 1, 1] = -c2 * r
    J[..., 1, 2] = -s2
    J[..., 2, 0] = c2 * s1 * r
    J[..., 2, 1] = c1 * s2 * r
    J[..., 2, 2] = -c1 * c2
    return J


def tip_pose_rcm(q: np.ndarray) -> np.ndarray:
    """Shaft-end pose in the RCM frame (4x4), orientation of frame 7 (wrist at zero); the
    dVRK's tool tip is `rig.model.psm_arm_kinematics.PSMKinematics.forward`."""
    return RCM_FRAME_INV @ frames(q)["tip"]


class IKError(ValueError):
    """A Cartesian target the first three joints cannot reach within limits."""


def ik_rcm(p: np.ndarray, check_limits: bool = True) -> np.ndarray:
    """Joints (q1, q2, q3) that put the tool tip at p (m, RCM frame). Closed form."""
    p = np.asarray(p, dtype=float)
    r = float(np.linalg.norm(p))
    if r < 1e-9:
        raise IKError("target is at the RCM: yaw and pitch are undefined there")
    # The tip lies on the insertion side (r = q3 - L_RCC + L_TOOL > 0 for q3 > 0.0156 m).
    q2 = float(np.arcsin(np.clip(-p[1] / r, -1.0, 1.0)))
    q1 = float(np.arctan2(p[0], -p[2]))
    q3 = r + L_RCC - L_TOOL
    q = np.array([q1, q2, q3])
    if check_limits:
        bad = (q < Q_MIN - 1e-12) | (q > Q_MAX + 1e-12)
        if bad.any():
            j = int(np.argmax(bad))
            raise IKError(f"joint {j + 1} would be {q[j]:.4f}, outside [{Q_MIN[j]}, {Q_MAX[j]}]")
    return q


def geometric_jacobian(q: np.ndarray, frame: str = "tip") -> np.ndarray:
    """6x3 geometric Jacobian of a frame in frame 0: [linear velocity; angular velocity].

    Built from the joint axes of the DH frames (eq. 4.1-4.3), the parallelogram's coupled
    rotations included: q2 turns frames 3 and 5 by +1 and frame 4 by -1 about parallel
    axes, so the net angular contribution of q2 is one rotation about z2.
    """
    T = frames(q)
    p = T[frame][:3, 3]
    J = np.zeros((6, 3))
    z1, o1 = T["1"][:3, 2], T["1"][:3, 3]
    J[:3, 0] = np.cross(z1, p - o1)
    J[3:, 0] = z1
    if frame in ("0", "1", "2"):
        if frame in ("0", "1"):
            J[:, 0] = 0.0
        return J
    # q2 drives revolute joints about z2 (origin 2: +1), z3 (origin 3: -1), z4 (origin 4: +1)
    # for frames beyond 5; fewer for frames 3 and 4; C1/C2 turn about z2 only.
    chain = {"3": [("2", 1.0)], "4": [("2", 1.0), ("3", -1.0)]}
    couplings = chain.get(frame, [("2", 1.0), ("3", -1.0), ("4", 1.0)])
    if frame in ("C1", "C2-int", "C2"):
        couplings = [("2", 1.0)]
    for parent, k in couplings:
        z, o = T[parent][:3, 2], T[parent][:3, 3]
        J[:3, 1] += k * np.cross(z, p - o)
        J[3:, 1] += k * z
    if frame in ("7", "8", "9", "10", "11", "tip"):
        J[:3, 2] = T["6"][:3, 2]
    elif frame == "C2":
        J[:3, 2] = DELTA_C2 * T["C2-int"][:3, 2]
    return J


def euler_zyx(R: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (yaw, pitch, roll) of a rotation matrix, rad."""
    yaw = np.arctan2(R[1, 0], R[0, 0])
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    roll = np.arctan2(R[2, 1], R[2, 2])
    return np.array([yaw, pitch, roll])


def euler_rate_map(angles: np.ndarray) -> np.ndarray:
    """T_A with omega = T_A d(angles)/dt for ZYX Euler angles (thesis 7.3, T_A^G)."""
    yaw, pitch, _ = angles
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.array([
        [0.0, -sy, cy * cp],
        [0.0, cy, sy * cp],
        [1.0, 0.0, -sp],
    ])


def analytic_jacobian(q: np.ndarray, frame: str = "tip") -> np.ndarray:
    """6x3 analytic Jacobian: [d position/dq; d ZYX Euler angles/dq] in frame 0."""
    J = geometric_jacobian(q, frame)
    angles = euler_zyx(frames(q)[frame][:3, :3])
    Ja = J.copy()
    Ja[3:] = np.linalg.solve(euler_rate_map(angles), J[3:])
    return Ja


@dataclass(frozen=True)
class JointLimits:
    """Table 4.2 limits for joints 1-3, as data (checked by --dry-run and the safety layer)."""

    q_min: np.ndarray = field(default_factory=Q_MIN.copy)
    q_max: np.ndarray = field(default_factory=Q_MAX.copy)
    dq_max: np.ndarray = field(default_factory=DQ_MAX.copy)

    def violation(self, q: np.ndarray, dq: np.ndarray | None = None, margin: float = 0.0) -> str | None:
        """A one-line description of the first limit broken, or None."""
        for j in range(3):
            if q[j] < self.q_min[j] - margin or q[j] > self.q_max[j] + margin:
                unit = "m" if j == 2 else "rad"
                return (f"joint {j + 1} position {q[j]:.4f} {unit} outside "
                        f"[{self.q_min[j]}, {self.q_max[j]}]")
        if dq is not None:
            for j in range(3):
                if abs(dq[j]) > self.dq_max[j]:
                    unit = "m/s" if j == 2 else "rad/s"
                    return f"joint {j + 1} velocity {dq[j]:.3f} {unit} above {self.dq_max[j]}"
        return None
