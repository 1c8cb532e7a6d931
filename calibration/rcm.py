"""Remote centre of motion from mocap (thesis appendix A.2): pivot fits, joint axes, the dVRK RCM frame.

The pivot fits of a tool body, the joints' axis directions, and the dVRK RCM frame they
define.

Input: the captures of `procedures.mocap_capture.measure_rcm_phases` (single-joint sweeps of q1 and
q2 and a Lissajous of both with q3 held), output: the pivot point (the RCM, mocap frame),
the tool offset, the yaw and pitch axes and the 4x4 RCM frame. Units: m, rad.
"""

from __future__ import annotations

import math

import numpy as np

from calibration.axis_fit import axis_angle, fit_axis_bias_compensated
from calibration.captures import Capture, body_points, concatenate
from calibration.fit_error import FitError
from calibration.joint_axis import joint_sign
from calibration.pivot import PivotFit, fit_pivot
from calibration.pivot_insertion import pivot_with_insertion

METHODS = ("one_step", "two_step", "sphere")


#: The sweeps and fits as `rig calibrate-rcm` does them by default (rad, m, s); `rig register`
#: measures RCM frames with these when it has no calibration of this rig.
DEFAULTS = {"q1_range": 1.2, "q2_range": 0.7, "q3": 0.12, "duration": 12.0, "method": "one_step",
            "ransac_threshold": 0.003, "q3_tolerance": 0.0005}


def pivot_all(R: np.ndarray, p: np.ndarray, threshold: float, primary: str) -> tuple[PivotFit, dict]:
    """Every pivot method with RANSAC; returns the primary fit and a summary of each."""
    fits = {}
    for m in METHODS:
        fits[m] = fit_pivot(R, p, method=m, ransac=True, threshold=threshold)
    table = {m: {"rcm": f.post.tolist(), "tip_offset": f.tip.tolist(), "rms": f.rms,
                 "rms_xyz": f.rms_xyz.tolist(), "rcm_std": f.post_std.tolist(),
                 "outliers": f.condition.get("outliers", 0)} for m, f in fits.items()}
    return fits[primary], {"fits": fits, "table": table}


def rcm_frame(rcm: np.ndarray, yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """The dVRK RCM frame (4x4, mocap) from the RCM point and the joints' positive axes:
    y = -yaw axis, x = -pitch axis made perpendicular to y, z = x cross y."""
    y = -np.asarray(yaw, float) / np.linalg.norm(yaw)
    x = -np.asarray(pitch, float)
    x = x - (x @ y) * y
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    T[:3, 3] = rcm
    return T


def joint_axis(cap: Capture, body: str, arm: str, joint: int) -> tuple[np.ndarray, float]:
    """Positive axis direction (mocap) of joint 1 or 2 from a body turning with it in a
    single-joint sweep (bias-compensated Gamage-Lasenby on its points), and its 1-sigma (rad)."""
    X, _ = body_points(cap, body)
    try:
        fit = fit_axis_bias_compensated(X)
    except FitError as exc:
        raise FitError(f"{arm} joint {joint} axis ({body} in the {cap.name}): {exc}", exc.condition) from None
    s = joint_sign(cap.poses[body][0], cap.joints[arm][:, joint - 1], fit.direction)
    return s * fit.direction, fit.direction_std


def calibrate_arm(caps: dict[str, Capture], arm: str, bodies: dict[str, str], parameters: dict) -> tuple[dict, PivotFit]:
    """Pivot calibration and RCM frame of one arm from its phases ("q1", "q2", "lissajous").

    bodies: "tool" (the pivot), "yaw" and "pitch" (bodies for the axis directions: the yaw
    link and the pitch end link when they carry bodies, else the tool). The result's RCM is
    the one-step fit with the insertion term (calibration.pivot_insertion) over every frame;
    the eq. A.10 family (one-step, two-step, sphere, each with RANSAC) is fitted on the
    frames whose q3 stayed within --q3-tolerance of its median and reported beside it.
    """
    body = bodies["tool"]
    allc = concatenate([caps[k] for k in ("q1", "q2", "lissajous") if k in caps], "all")
    q3 = allc.joints[arm][:, 2]
    R, p = allc.poses[body]
    fit, v = pivot_with_insertion(R, p, q3, reject=parameters["ransac_threshold"])
    keep = np.abs(q3 - np.median(q3)) <= parameters["q3_tolerance"]
    Rk = np.where(keep[:, None, None], R, np.nan)
    pk = np.where(keep[:, None], p, np.nan)
    try:
        a10, all_fits = pivot_all(Rk, pk, parameters["ransac_threshold"], parameters["method"])
        table = all_fits["table"]
    except FitError as exc:  # the insertion-compensated fit stands; say why the others could not
        table = {"refused": str(exc)}
    yaw, yaw_std = joint_axis(caps["q1"], bodies["yaw"], arm, 1)
    pitch, pitch_std = joint_axis(caps["q2"], bodies["pitch"], arm, 2)
    F = rcm_frame(fit.post, yaw, pitch)
    out = {**fit.summary(), "methods": table, "rcm_frame": F.tolist(),
           "insertion_shift_per_m": v.tolist(),
           "yaw_axis": yaw.tolist(), "pitch_axis": pitch.tolist(),
           "yaw_axis_std_deg": math.degrees(yaw_std), "pitch_axis_std_deg": math.degrees(pitch_std),
           "yaw_pitch_angle_deg": math.degrees(axis_angle(yaw, pitch)),
           "frames_q3_held": int(keep.sum()), "q3_spread": float(np.ptp(q3)), "bodies": bodies}
    return out, fit


def arm_bodies(arm: str, tracked) -> dict[str, str]:
    """The tool body and the bodies giving the yaw and pitch axes (tool if absent)."""
    tool = f"{arm}_tool"
    return {"tool": tool, "yaw": f"{arm}_yaw" if f"{arm}_yaw" in tracked else tool,
            "pitch": f"{arm}_pitch_end" if f"{arm}_pitch_end" in tracked else tool}
