"""Kinematics of the whole dVRK PSM with a tool: forward, Jacobians and inverse as the dVRK computes them.

Why: `rig sim` stands in for a dVRK PSM, so the pose it reports as `local/measured_cp`, the
Jacobians behind `body/measured_cf` and `spatial/measured_cf`, and the joints it chooses
for a `servo_cp` must be the dVRK's, tool tip and all. rig.model.psm_kinematics (thesis Table
4.3) stops at joint 3; this module adds the instrument (rig.model.psm_tool) the way the dVRK
does, from the same facts (share/kinematic/PSM.json and share/tool/*.json, commit in
rig.model.psm_tool.DVRK_COMMIT), without its code.

What the dVRK computes (mtsIntuitiveResearchKitArm.cpp, mtsIntuitiveResearchKitPSM.cpp):

* Chain: the three rows of PSM.json, then the tool's three rows (ConfigureTool truncates the
  manipulator to 3 links and appends the tool's), then the tool's `tooltip_offset` attached
  as a fixed transform. `local/measured_cp` = ForwardKinematics(q) of that chain, in the
  arm's kinematic base frame: origin at the remote centre of motion (RCM), the shaft along
  -z at q = 0. `measured_cp` is base_frame * local/measured_cp; this module stops at local.
* Joint 3 carries offset -0.4318 m (l_RCC) and the roll row D = 0.4162 m (the tool length),
  so frame 4 (the roll frame, on the wrist-pitch axis: "the shaft end") sits
  r = q3 - 0.4318 + 0.4162 m from the RCM along the shaft; the wrist-yaw row's A (0.0091 m
  for the large needle driver) puts the tip on the wrist-yaw axis, that far beyond.
* The files write pi/2 as 1.5708 (7.3e-6 rad short). With `exact_right_angles=True` (the
  default) every alpha/offset within 1e-4 of +-pi/2 is taken as +-pi/2: the instrument is
  built with right angles, the RCM is then exact and joints 1-3 agree with
  rig.model.psm_kinematics to machine precision. The dVRK computes with 1.5708 as written;
  `exact_right_angles=False` does the same (the two differ by at most 2.9e-6 m and
  2.2e-5 rad over the joint ranges; tests/rig/model/test_psm_arm_kinematics.py checks it).

Jacobians (both 6x6, rows [linear x, y, z; angular x, y, z], columns joints 1-6):

* The arm computes body/measured_cf as pinv(J_body^T) tau and then rotates its first three
  and its last three entries by measured_cp's rotation to get the absolute wrench, and
  local/measured_cv as J_body dq, whose first three entries it calls linear. So J_body maps
  dq to [v; w] with force/linear first and both expressed in the tool-tip frame; v is the
  velocity of the tip's origin (a body twist's linear part is that of the frame's own
  origin). spatial/measured_cf = pinv(J_spatial^T) tau is published as is, so
  J_spatial's rows are in the base frame. Which point its linear rows refer to cannot be
  read from that use; cisst's robManipulator (cisstRobot/code/robManipulator.cpp, read as
  a cross-check) builds it as Ad(T) J_body with Ad = [[R, [p]x R], [0, R]]: the spatial
  twist of screw theory, v_s = v_tip + p x w, i.e. the velocity of the body point at the
  base origin (the RCM). Hence J_spatial = Ad(forward(q)) J_body, tested here.
  Its wrench is the force and the moment about the RCM, in the base frame.
* Paul's body Jacobian (cisst's JacobianBody) counts the tool-tip offset (the attached
  tool is part of U), so J_body is the tip's.

Inverse: the dVRK runs cisst's damped least-squares iteration from the measured joints,
wraps revolute joints to [-pi, pi], then moves joint 4 by whole turns to the one closest
to the measured roll (PSM::InverseKinematics), and refuses a goal within 1 mm of the RCM.
For the 6-joint PSM the solution is closed form and unique up to one flip: the tip lies on
the wrist-yaw axis, the wrist-pitch point lies on the shaft line through the RCM, and the
wrist-pitch axis is perpendicular to the shaft, which leaves x5 = +-(cos t6 x6 - sin t6 y6)
with tan t6 = -(p.y6)/(p.x6). The flip turns wrist yaw by pi, so with wrist yaw inside
+-90 deg (every tool's range) the other branch is outside its limits; among the branches
within limits the one closest to the seed is kept, as the dVRK's iteration from the
measured joints would find, and joint 4 goes to the turn closest to the seed's roll within
its +-260 deg. A Newton step on the full Jacobian then polishes the result (needed with
`exact_right_angles=False` only). Where the dVRK would clip a solution outside the joint
limits to them (clip_jp, before the PID), this raises IKError naming the joint.
`inverse(..., keep_safe_distance=True)` also applies the dVRK's RCM guard: the shaft end
(frame 4) is kept SAFE_DISTANCE_FROM_RCM = 0.045 m out by limiting insertion, as
PSM::InverseKinematics does with the seed as the current depth.

Today's 3-joint model (rig.model.psm_kinematics) against the dVRK's frames, found numerically
and tested (tests/rig/model/test_psm_arm_kinematics.py):

* Base: rig.model.psm_kinematics' "RCM frame" IS the dVRK's PSM kinematic base frame:
  RCM_FRAME_TO_BASE is the identity; tip_in_rcm(q[:3]) equals shaft_point(q) to 1e-15 m.
* Tip: what rig.model.psm_kinematics calls the tool tip is the shaft end (frame 4's origin, the
  wrist-pitch axis point), not the dVRK's tool tip, and its orientation is the dVRK's turned
  by -90 deg about the shaft. With the wrist at 0, for every q1..q3,
  forward(q) = tip_pose_rcm(q[:3]) @ RIG_TIP_TO_TOOL_TIP, where RIG_TIP_TO_TOOL_TIP is Rz(+90
  deg) followed by the wrist-yaw length (0.0091 m for the large needle driver) along the
  shaft (+z of both tip frames): the "9 mm short, 90 deg about the shaft" of the issue.

Units: m and rad (joint 3 in m). Joint vectors are (6,): yaw, pitch, insertion, roll,
wrist pitch, wrist yaw; the jaw is not a kinematic joint (rig.model.wrist_plant moves it).
"""

from __future__ import annotations

import math

import numpy as np

from rig.model.psm_tool import DEFAULT_TOOL, PSM_DH, PSM_Q_MAX, PSM_Q_MIN, SAFE_DISTANCE_FROM_RCM, DHRow, Tool

JOINT_NAMES = ("outer_yaw", "outer_pitch", "outer_insertion", "outer_roll",
               "outer_wrist_pitch", "outer_wrist_yaw")

# rig.model.psm_kinematics' RCM frame -> the dVRK's PSM kinematic base frame (they are the same).
RCM_FRAME_TO_BASE = np.eye(4)

# rig.model.psm_kinematics.tip_pose_rcm(q[:3]) @ RIG_TIP_TO_TOOL_TIP = the dVRK's tool-tip pose at
# wrist 0, for the large needle driver (PSMKinematics.rig_tip_to_tool_tip for any tool).
RIG_TIP_TO_TOOL_TIP = np.array([
    [0.0, -1.0, 0.0, 0.0],
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, DEFAULT_TOOL.wrist_yaw_length],
    [0.0, 0.0, 0.0, 1.0],
])

# The dVRK refuses an inverse-kinematics goal this close to the RCM (PSM::InverseKinematics).
IK_MIN_DISTANCE_TO_RCM = 0.001  # m
# Joint limits are checked with this slack (rad, m), so targets made from a pose at a limit pass.
LIMIT_TOLERANCE = 1e-9

_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi


class IKError(ValueError):
    """A tool-tip pose the PSM cannot reach within its joint limits, or too close to the RCM."""


def _snap(x: float, exact: bool) -> float:
    if exact and abs(abs(x) - _HALF_PI) < 1e-4:
        return math.copysign(_HALF_PI, x)
    return x


def _wrap(x: float) -> float:
    """Angle to [-pi, pi)."""
    return (x + math.pi) % _TWO_PI - math.pi


def adjoint(T: np.ndarray) -> np.ndarray:
    """6x6 adjoint [[R, [p]x R], [0, R]] of a pose: maps a body twist [v; w] to the base frame."""
    R, p = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    px = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
    A[:3, 3:] = px @ R
    return A


def rotation_error(R_goal: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector (base frame, rad) that turns R into R_goal: log(R_goal R^T)."""
    E = R_goal @ R.T
    w = np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    s = 0.5 * float(np.linalg.norm(w))
    c = 0.5 * (float(E[0, 0] + E[1, 1] + E[2, 2]) - 1.0)
    angle = math.atan2(s, c)
    if s < 1e-12:
        if c > 0.0:
            return 0.5 * w
        # half a turn: axis from the symmetric part
        B = 0.5 * (E + np.eye(3))
        k = int(np.argmax(np.diag(B)))
        axis = B[:, k] / math.sqrt(max(B[k, k], 1e-300))
        return math.pi * axis
    return (angle / (2.0 * s)) * w


class PSMKinematics:
    """The dVRK's PSM + tool chain: six joints, tool-tip pose, Jacobians and inverse.

    With exact right angles (the default) forward and the Jacobians are closed form (median
    on this project's 2-core machine: forward 8 us, jacobian_body 19 us, jacobian_spatial
    25 us, forward_and_jacobians 31 us, inverse 105-110 us); with the rows as written they
    multiply the seven 4x4 matrices of the chain (19, 55 and 440 us).
    """

    joint_names = JOINT_NAMES

    def __init__(self, tool: Tool = DEFAULT_TOOL, exact_right_angles: bool = True):
        self.tool = tool
        self.exact_right_angles = bool(exact_right_angles)
        rows: tuple[DHRow, ...] = PSM_DH + tool.dh
        self._links = []
        for row in rows:
            alpha = _snap(row.alpha, exact_right_angles)
            offset = _snap(row.offset, exact_right_angles) if row.revolute else row.offset
            ca, sa = math.cos(alpha), math.sin(alpha)
            if abs(ca) < 1e-15:
                ca = 0.0
            if abs(sa) < 1e-15:
                sa = 0.0
            self._links.append((ca, sa, row.a, row.theta, row.d, offset, row.revolute))
        self._revolute = np.array([row.revolute for row in rows])
        self.q_min = np.array(PSM_Q_MIN + tool.q_min, dtype=float)
        self.q_max = np.array(PSM_Q_MAX + tool.q_max, dtype=float)
        self.tip_offset = tool.tooltip_offset_matrix
        self._tip_offset_inv = np.linalg.inv(self.tip_offset)
        self.wrist_yaw_length = tool.wrist_yaw_length
        self._L = [np.eye(4) for _ in rows]
        # constant entries of each link matrix Rx(alpha) Tx(a) Rz(theta) Tz(d)
        for L, (ca, sa, a, _t, _d, _o, _r) in zip(self._L, self._links):
            L[0, 2] = 0.0
            L[0, 3] = a
            L[1, 2] = -sa
            L[2, 2] = ca
        # shaft end's distance from the RCM is q3 + _r0 (joint 3's offset + the roll row's D)
        self._r0 = self._links[2][5] + self._links[2][4] + self._links[3][4]
        self.rig_tip_to_tool_tip = self._rig_tip_to_tool_tip()

    # ------------------------------------------------------------------ forward
    # Two implementations of the same chain. The generic one multiplies the seven 4x4
    # matrices of the rows as written (any alpha, used with exact_right_angles=False). The
    # closed form below holds for the PSM's rows with exact right angles (the default) and
    # is 3-5 times faster; tests hold the two together to 1e-15. With right angles:
    #   R3 = [x3, y3, z3] = [(-s1 s2, -c2, c1 s2), (-c1, 0, -s1), (s1 c2, -s2, -c1 c2)]
    #   x4 = c4 x3 + s4 y3, y4 = -s4 x3 + c4 y3, z4 = z3, o4 = r z3 (r = q3 - 0.4318 + D4)
    #   x5 = s5 x4 + c5 z4, y5 = c5 x4 - s5 z4, z5 = y4, o5 = o4
    #   x6 = s6 x5 + c6 z5, y6 = c6 x5 - s6 z5, z6 = y5, o6 = o4 + a6 x5
    def _link(self, i: int, qi: float) -> np.ndarray:
        ca, sa, _a, theta, d, offset, revolute = self._links[i]
        if revolute:
            theta = theta + qi + offset
        else:
            d = d + qi + offset
        ct, st = math.cos(theta), math.sin(theta)
        L = self._L[i]
        L[0, 0] = ct
        L[0, 1] = -st
        L[1, 0] = st * ca
        L[1, 1] = ct * ca
        L[1, 3] = -sa * d
        L[2, 0] = st * sa
        L[2, 1] = ct * sa
        L[2, 3] = ca * d
        return L

    def _generic_frames(self, q: np.ndarray) -> list[np.ndarray]:
        out = []
        W = self._link(0, float(q[0])).copy()
        out.append(W)
        for i in range(1, 6):
            W = W @ self._link(i, float(q[i]))
            out.append(W)
        out.append(W @ self.tip_offset)
        return out

    def _closed_form_vectors(self, q) -> tuple:
        """Axes and origins of frames 3-6 (tuples of 3 floats), exact right angles only."""
        q1, q2, q3, q4, q5, q6 = (float(x) for x in q[:6])
        s1, c1, s2, c2 = math.sin(q1), math.cos(q1), math.sin(q2), math.cos(q2)
        s4, c4 = math.sin(q4), math.cos(q4)
        s5, c5, s6, c6 = math.sin(q5), math.cos(q5), math.sin(q6), math.cos(q6)
        x3 = (-s1 * s2, -c2, c1 * s2)
        y3 = (-c1, 0.0, -s1)
        z3 = (s1 * c2, -s2, -c1 * c2)
        x4 = (c4 * x3[0] + s4 * y3[0], c4 * x3[1], c4 * x3[2] + s4 * y3[2])
        y4 = (-s4 * x3[0] + c4 * y3[0], -s4 * x3[1], -s4 * x3[2] + c4 * y3[2])
        x5 = (s5 * x4[0] + c5 * z3[0], s5 * x4[1] + c5 * z3[1], s5 * x4[2] + c5 * z3[2])
        y5 = (c5 * x4[0] - s5 * z3[0], c5 * x4[1] - s5 * z3[1], c5 * x4[2] - s5 * z3[2])
        x6 = (s6 * x5[0] + c6 * y4[0], s6 * x5[1] + c6 * y4[1], s6 * x5[2] + c6 * y4[2])
        y6 = (c6 * x5[0] - s6 * y4[0], c6 * x5[1] - s6 * y4[1], c6 * x5[2] - s6 * y4[2])
        r = q3 + self._r0
        a6 = self.wrist_yaw_length
        o4 = (r * z3[0], r * z3[1], r * z3[2])
        o6 = (o4[0] + a6 * x5[0], o4[1] + a6 * x5[1], o4[2] + a6 * x5[2])
        return z3, y4, y5, x6, y6, o4, o6

    def _frame6(self, q) -> np.ndarray:
        z3, y4, y5, x6, y6, o4, o6 = self._closed_form_vectors(q)
        return np.array([[x6[0], y6[0], y5[0], o6[0]],
                         [x6[1], y6[1], y5[1], o6[1]],
                         [x6[2], y6[2], y5[2], o6[2]],
                         [0.0, 0.0, 0.0, 1.0]])

    def frames(self, q: np.ndarray) -> list[np.ndarray]:
        """The six DH frames (4x4, base frame) after joints 1..6, then the tool tip."""
        return self._generic_frames(np.asarray(q, dtype=float))

    def forward(self, q: np.ndarray) -> np.ndarray:
        """Tool-tip pose (4x4) in the PSM's kinematic base frame: the dVRK's local/measured_cp."""
        if self.exact_right_angles:
            return self._frame6(q) @ self.tip_offset
        q = np.asarray(q, dtype=float)
        W = self._link(0, float(q[0])) @ self._link(1, float(q[1]))
        for i in range(2, 6):
            W = W @ self._link(i, float(q[i]))
        return W @ self.tip_offset

    def shaft_frame(self, q: np.ndarray) -> np.ndarray:
        """Frame 4 (4x4): on the wrist-pitch axis at the end of the shaft, turned by the roll."""
        q = np.asarray(q, dtype=float)
        W = self._link(0, float(q[0])) @ self._link(1, float(q[1]))
        W = W @ self._link(2, float(q[2]))
        return W @ self._link(3, float(q[3]))

    def shaft_point(self, q: np.ndarray) -> np.ndarray:
        """The wrist-pitch axis point at the end of the shaft (3,), m: today's 3-joint "tip"."""
        if self.exact_right_angles:
            q1, q2 = float(q[0]), float(q[1])
            r = float(q[2]) + self._r0
            c2 = math.cos(q2)
            return np.array([c2 * math.sin(q1) * r, -math.sin(q2) * r, -math.cos(q1) * c2 * r])
        return self.shaft_frame(q)[:3, 3].copy()

    # ---------------------------------------------------------------- Jacobians
    def _hybrid(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip pose and the 6x6 Jacobian [tip point velocity; angular velocity] in the base."""
        if self.exact_right_angles:
            return self._hybrid_closed_form(q)
        F = self._generic_frames(np.asarray(q, dtype=float))
        T = F[6]
        p = T[:3, 3]
        S = np.stack(F[:6])                # (6, 4, 4)
        Z = S[:, :3, 2].T                  # joint axes (3, 6)
        D = p[:, None] - S[:, :3, 3].T     # tip minus joint origins (3, 6)
        J = np.empty((6, 6))
        J[0] = Z[1] * D[2] - Z[2] * D[1]
        J[1] = Z[2] * D[0] - Z[0] * D[2]
        J[2] = Z[0] * D[1] - Z[1] * D[0]
        J[3:] = Z
        pris = ~self._revolute
        J[:3, pris] = Z[:, pris]
        J[3:, pris] = 0.0
        return T, J

    def _hybrid_closed_form(self, q) -> tuple[np.ndarray, np.ndarray]:
        z3, y4, y5, x6, y6, o4, o6 = self._closed_form_vectors(q)
        T6 = np.array([[x6[0], y6[0], y5[0], o6[0]],
                       [x6[1], y6[1], y5[1], o6[1]],
                       [x6[2], y6[2], y5[2], o6[2]],
                       [0.0, 0.0, 0.0, 1.0]])
        T = T6 @ self.tip_offset
        px, py, pz = float(T[0, 3]), float(T[1, 3]), float(T[2, 3])
        # joint 1 about z1 = (0, -1, 0) and joint 2 about z2 = (-c1, 0, -s1), both through
        # the RCM; joint 3 along z3; joints 4, 5 about z3, y4 through o4; joint 6 about y5
        # through o6.
        q1 = float(q[0])
        c1, s1 = math.cos(q1), math.sin(q1)
        dx, dy, dz = px - o4[0], py - o4[1], pz - o4[2]
        ex, ey, ez = px - o6[0], py - o6[1], pz - o6[2]
        J = np.array([
            [-pz, s1 * py, z3[0], z3[1] * dz - z3[2] * dy, y4[1] * dz - y4[2] * dy,
             y5[1] * ez - y5[2] * ey],
            [0.0, c1 * pz - s1 * px, z3[1], z3[2] * dx - z3[0] * dz, y4[2] * dx - y4[0] * dz,
             y5[2] * ex - y5[0] * ez],
            [px, -c1 * py, z3[2], z3[0] * dy - z3[1] * dx, y4[0] * dy - y4[1] * dx,
             y5[0] * ey - y5[1] * ex],
            [0.0, -c1, 0.0, z3[0], y4[0], y5[0]],
            [-1.0, 0.0, 0.0, z3[1], y4[1], y5[1]],
            [0.0, -s1, 0.0, z3[2], y4[2], y5[2]],
        ])
        return T, J

    def jacobian_body(self, q: np.ndarray) -> np.ndarray:
        """6x6 body Jacobian (cisst JacobianBody): dq -> [v; w] of the tip in the tip frame."""
        T, J = self._hybrid(q)
        return self._body_from_hybrid(T, J)

    def jacobian_spatial(self, q: np.ndarray) -> np.ndarray:
        """6x6 spatial Jacobian (cisst JacobianSpatial = Ad(T) J_body): base frame, at the RCM."""
        T, J = self._hybrid(q)
        return self._spatial_from_hybrid(T, J)

    @staticmethod
    def _body_from_hybrid(T: np.ndarray, J: np.ndarray) -> np.ndarray:
        Rt = T[:3, :3].T
        Jb = np.empty((6, 6))
        np.matmul(Rt, J[:3], out=Jb[:3])
        np.matmul(Rt, J[3:], out=Jb[3:])
        return Jb

    @staticmethod
    def _spatial_from_hybrid(T: np.ndarray, J: np.ndarray) -> np.ndarray:
        p = T[:3, 3]
        Js = J.copy()
        W = J[3:]
        Js[0] += p[1] * W[2] - p[2] * W[1]
        Js[1] += p[2] * W[0] - p[0] * W[2]
        Js[2] += p[0] * W[1] - p[1] * W[0]
        return Js

    def forward_and_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tip pose, body Jacobian, spatial Jacobian) in one pass, for a control tick."""
        T, J = self._hybrid(q)
        return T, self._body_from_hybrid(T, J), self._spatial_from_hybrid(T, J)

    # ------------------------------------------------------------------ inverse
    def inverse(self, T: np.ndarray, q_seed: np.ndarray | None = None,
                keep_safe_distance: bool = False) -> np.ndarray:
        """Joints (6,) that put the tool tip at pose T (base frame), the dVRK's choice.

        q_seed: the measured joints the dVRK would start from (default: zeros, q3 = 0.12 m).
        Raises IKError when the pose is within 1 mm of the RCM, degenerate, or needs a joint
        outside its limits. keep_safe_distance applies the dVRK's RCM guard (module doc).
        """
        T = np.asarray(T, dtype=float)
        if q_seed is None:
            q_seed = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
        seed = np.asarray(q_seed, dtype=float)
        p_goal = T[:3, 3]
        if float(np.linalg.norm(p_goal)) < IK_MIN_DISTANCE_TO_RCM:
            raise IKError("inverse kinematics: the goal is within 1 mm of the RCM")
        T6 = T @ self._tip_offset_inv      # the wrist-yaw frame (frame 6)
        candidates = self._closed_form_ik(T6, seed)
        best, best_cost, first_bad = None, math.inf, None
        for q in candidates:
            bad = self._limit_violation(q)
            if bad is not None:
                first_bad = first_bad or bad
                continue
            cost = float(np.sum((q - seed) ** 2))
            if cost < best_cost:
                best, best_cost = q, cost
        if best is None:
            raise IKError(first_bad or "inverse kinematics: no solution")
        q = self._polish(best, T)
        if keep_safe_distance:
            q = self._keep_safe_distance(q, float(seed[2]))
        return q

    def _closed_form_ik(self, T6: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
        p = T6[:3, 3].tolist()
        x6 = T6[:3, 0].tolist()
        y6 = T6[:3, 1].tolist()
        a6 = self.wrist_yaw_length
        px = p[0] * x6[0] + p[1] * x6[1] + p[2] * x6[2]
        py = p[0] * y6[0] + p[1] * y6[1] + p[2] * y6[2]
        if math.hypot(px, py) < 1e-12:
            # the wrist-yaw axis passes through the RCM: yaw is free, keep the seed's
            t6s = [float(seed[5]) - _HALF_PI]
        else:
            t = math.atan2(-py, px)
            t6s = [t, t + math.pi]
        out = []
        for t6 in t6s:
            c6, s6 = math.cos(t6), math.sin(t6)
            x5 = [c6 * x6[i] - s6 * y6[i] for i in range(3)]
            z5 = [-s6 * x6[i] - c6 * y6[i] for i in range(3)]
            o4 = [p[i] - a6 * x5[i] for i in range(3)]
            r = math.sqrt(o4[0] ** 2 + o4[1] ** 2 + o4[2] ** 2)
            if r < 1e-9:
                continue
            d = [o4[i] / r for i in range(3)]
            q2 = math.asin(max(-1.0, min(1.0, -d[1])))
            q1 = math.atan2(d[0], -d[2])
            q3 = r - self._r0
            s1, c1, s2, c2 = math.sin(q1), math.cos(q1), math.sin(q2), math.cos(q2)
            x3 = (-s1 * s2, -c2, c1 * s2)
            y3 = (-c1, 0.0, -s1)
            # z5 = y4 = -s4 x3 + c4 y3
            t4 = math.atan2(-(x3[0] * z5[0] + x3[1] * z5[1] + x3[2] * z5[2]),
                            y3[0] * z5[0] + y3[2] * z5[2])
            c4, s4 = math.cos(t4), math.sin(t4)
            x4 = (c4 * x3[0] + s4 * y3[0], c4 * x3[1], c4 * x3[2] + s4 * y3[2])
            # x5 = s5 x4 + c5 z4 with z4 = d
            q5 = math.atan2(x4[0] * x5[0] + x4[1] * x5[1] + x4[2] * x5[2],
                            d[0] * x5[0] + d[1] * x5[1] + d[2] * x5[2])
            q6 = _wrap(t6 + _HALF_PI)
            q4 = self._closest_roll(_wrap(t4), float(seed[3]))
            out.append(np.array([q1, q2, q3, q4, q5, q6]))
        return out

    def _closest_roll(self, q4: float, seed4: float) -> float:
        """q4 + k 2 pi closest to the seed's roll, preferring one within the roll limits."""
        k = round((seed4 - q4) / _TWO_PI)
        options = [q4 + (k + dk) * _TWO_PI for dk in (0, -1, 1, -2, 2)]
        lo, hi = self.q_min[3] - LIMIT_TOLERANCE, self.q_max[3] + LIMIT_TOLERANCE
        inside = [x for x in options if lo <= x <= hi]
        pool = inside or options
        return min(pool, key=lambda x: abs(x - seed4))

    def _limit_violation(self, q: np.ndarray) -> str | None:
        lo = q < self.q_min - LIMIT_TOLERANCE
        hi = q > self.q_max + LIMIT_TOLERANCE
        if lo.any() or hi.any():
            j = int(np.argmax(lo | hi))
            unit = "m" if j == 2 else "rad"
            return (f"inverse kinematics: {JOINT_NAMES[j]} would be {q[j]:.6f} {unit}, "
                    f"outside [{self.q_min[j]:.6f}, {self.q_max[j]:.6f}]")
        return None

    def _polish(self, q: np.ndarray, T: np.ndarray, iterations: int = 6) -> np.ndarray:
        """Newton steps on [position; rotation vector] while the pose is off by over 1e-12.

        With exact right angles the closed form is already exact and no step is taken.
        """
        q = q.copy()
        for _ in range(iterations):
            Tq = self.forward(q)
            err = T - Tq
            if float(np.max(np.abs(err[:3]))) < 1e-12:
                break
            _, J = self._hybrid(q)
            e = np.empty(6)
            e[:3] = err[:3, 3]
            e[3:] = rotation_error(T[:3, :3], Tq[:3, :3])
            q += np.linalg.lstsq(J, e, rcond=None)[0]
        bad = self._limit_violation(q)
        if bad is not None:
            raise IKError(bad)
        return q

    def _keep_safe_distance(self, q: np.ndarray, current_depth: float) -> np.ndarray:
        """The dVRK's guard: keep frame 4 SAFE_DISTANCE_FROM_RCM out by limiting insertion."""
        distance = float(np.linalg.norm(self.shaft_point(q)))
        if distance >= SAFE_DISTANCE_FROM_RCM:
            return q
        q = q.copy()
        min_depth = q[2] + (SAFE_DISTANCE_FROM_RCM - distance)
        q[2] = max(current_depth, q[2]) if current_depth <= min_depth else min_depth
        return q

    # ------------------------------------------------------------- today's model
    def _rig_tip_to_tool_tip(self) -> np.ndarray:
        """Fixed transform from rig.model.psm_kinematics' tip frame to this tool's tip at wrist 0."""
        from rig.model import psm_kinematics as K

        q = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
        X = np.linalg.inv(K.tip_pose_rcm(q[:3])) @ self.forward(q)
        X[np.abs(X) < 1e-12] = 0.0
        return X


_DEFAULT_KINEMATICS: PSMKinematics | None = None


def tool_tip_in_rcm(q, wrist=None, kinematics: PSMKinematics | None = None) -> np.ndarray:
    """The dVRK's tool tip (on the wrist-yaw axis, where a person brings two tools together)
    in the RCM frame (m), from joints 1-3 `q` (rad, rad, m) and the wrist's roll, pitch and
    yaw `wrist` (rad; None: a straight wrist, all 0, as an arm that reports joints 1-3
    only). rig.model.psm_kinematics.tip_in_rcm is the shaft end, the tool's wrist-yaw
    length (9.1 mm for the large needle driver) short of it."""
    global _DEFAULT_KINEMATICS
    if kinematics is None:
        if _DEFAULT_KINEMATICS is None:
            _DEFAULT_KINEMATICS = PSMKinematics()
        kinematics = _DEFAULT_KINEMATICS
    full = np.concatenate([np.asarray(q, float)[:3], np.zeros(3) if wrist is None else np.asarray(wrist, float)[:3]])
    return (RCM_FRAME_TO_BASE @ kinematics.forward(full))[:3, 3].copy()
