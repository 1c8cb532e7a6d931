"""A slave's Cartesian impedance run by the arm itself: the dVRK's `servo_ci` goal.

The cooperative controller (`rig.control.cooperative_controller`) plans its slaves' impedance at the shaft
end (the 3-joint model's tip, where the object is held) in the RCM frame, with joint-space
feedforward from the identified model. The dVRK's `osaCartesianImpedanceController` runs a
spring, a damper and a bias about a tool-tip pose in its servo loop (crtk_msgs/
CartesianImpedance, read from sawIntuitiveResearchKit's mtsIntuitiveResearchKitArm and
osaCartesianImpedanceController): per axis of a force frame F, with e the tool tip's
displacement from the goal and v its velocity, both in F,

    f_F = -K e - D v + b,      the wrench (f, torque) applied through the body Jacobian.

`servo_ci_goal` turns the controller's plan into that goal:

* the goal position is the measured tool tip moved by the shaft end's error to its
  target (the wrist is held rigid, so both points move together);
* the force frame's x axis is the object's direction u: one stiffness and damping along
  it, another across;
* the damper acts on the tool tip's absolute velocity (the message has no velocity goal),
  so the bias carries D v_d, which makes it D (v_d - v);
* the bias also carries the model's joint-space feedforward tau (gravity, planned
  acceleration, friction and its offsets), as the tool-tip wrench whose J_body^T gives it
  on joints 1-3 and nothing on the wrist: w = J_body^-T (tau, 0). As a force alone it
  would turn the wrist (the gravity of joint 2, ~2 N m, is ~17 N at the tip, 0.15 N m on
  the wrist's 9.1 mm lever), and with it the tool tip the goal is about;
* the orientation is held where the tool tip points (torque stiffness and damping on the
  wrist), so the wrist keeps the force's lever constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.model import psm_kinematics as K
from rig.model.psm_arm_kinematics import PSMKinematics

#: N m/rad and N m s/rad holding the tool tip's orientation (the wrist's joints): a 5 N
#: force at the 9.1 mm tool-tip lever turns the wrist by 0.045 N m / 2 = 0.02 rad, and
#: 0.02 N m s/rad damps the wrist's ~1e-4 kg m^2 at about 0.7.
TORQUE_STIFFNESS = 2.0
TORQUE_DAMPING = 0.02


@dataclass
class ServoCIGoal:
    """The arguments of `RosArm.servo_ci` (the arm's base frame, SI units)."""

    position: np.ndarray          # tool-tip goal (m)
    orientation: np.ndarray       # tool-tip orientation held (3x3)
    force_orientation: np.ndarray  # axes of the force gains (3x3, columns in the base frame)
    stiffness: np.ndarray         # N/m per force axis, >= 0
    damping: np.ndarray           # N s/m per force axis, >= 0
    bias: np.ndarray              # N per force axis
    torque_bias: np.ndarray       # N m per axis of `orientation`
    torque_stiffness: np.ndarray  # N m/rad
    torque_damping: np.ndarray    # N m s/rad


def force_frame(u: np.ndarray) -> np.ndarray:
    """A right-handed frame (3x3, columns) whose x axis is the unit vector u (its cross
    products written out: np.cross costs 40 us a call, and this runs every tick)."""
    ux, uy, uz = (float(v) for v in u)
    n = max(np.sqrt(ux * ux + uy * uy + uz * uz), 1e-12)
    x = (ux / n, uy / n, uz / n)
    hx, hy, hz = (0.0, 0.0, 1.0) if abs(x[2]) < 0.9 else (1.0, 0.0, 0.0)
    # y = helper x x, normalised; z = x x y
    y = (hy * x[2] - hz * x[1], hz * x[0] - hx * x[2], hx * x[1] - hy * x[0])
    m = np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
    y = (y[0] / m, y[1] / m, y[2] / m)
    z = (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])
    return np.array([[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]])


def servo_ci_goal(kinematics: PSMKinematics, q6: np.ndarray, target: np.ndarray, velocity: np.ndarray,
                  u: np.ndarray, stiffness: np.ndarray, damping: np.ndarray,
                  feedforward: np.ndarray, orientation: np.ndarray | None = None) -> ServoCIGoal:
    """The servo_ci goal for a slave at joints `q6` (measured, 6) whose shaft end should be
    at `target` (m, RCM frame = the arm's kinematic base) moving at `velocity` (m/s), with
    the object along `u` (unit, RCM frame); `stiffness` and `damping` (3,) on the axes of
    `force_frame(u)` (along u first);
    `feedforward`: joint torques (N m, N m, N) for joints 1-3; `orientation`: the tool-tip
    orientation to hold (default: the measured one)."""
    q6 = np.asarray(q6, float)
    T, Jb, _ = kinematics.forward_and_jacobians(q6)
    R = T[:3, :3]
    shaft = K.tip_in_rcm(q6[:3])
    position = T[:3, 3] + (np.asarray(target, float) - shaft)
    Rf = force_frame(u)
    k = np.asarray(stiffness, float)
    d = np.asarray(damping, float)
    w_body = np.linalg.solve(Jb.T, np.concatenate([np.asarray(feedforward, float)[:3], np.zeros(3)]))
    Rt = R.copy() if orientation is None else np.asarray(orientation, float)
    bias = Rf.T @ (R @ w_body[:3]) + d * (Rf.T @ np.asarray(velocity, float))
    return ServoCIGoal(position=position, orientation=Rt, torque_bias=Rt.T @ (R @ w_body[3:]),
                       force_orientation=Rf, stiffness=k, damping=d, bias=bias,
                       torque_stiffness=np.full(3, TORQUE_STIFFNESS), torque_damping=np.full(3, TORQUE_DAMPING))


def cartesian_inertia(mass_matrix: np.ndarray, J: np.ndarray, axis: np.ndarray) -> float:
    """The arm's inertia (kg) seen along the unit `axis` at the tip with Jacobian J (3x3):
    1 / (a^T J M^-1 J^T a), the mass a force along `axis` accelerates."""
    a = np.asarray(axis, float)
    return float(1.0 / (a @ J @ np.linalg.solve(mass_matrix, J.T @ a)))
