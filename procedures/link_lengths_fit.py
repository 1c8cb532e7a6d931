"""The geometry of `rig link-lengths`: joint axes fitted to the marker bodies' motion, the
lengths of Table 4.1 between them, and the DH parameters they imply (the procedure's
module docstring says how). Units: m and rad."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.axis_fit import (AxisFit, axis_angle, axis_distance, common_perpendicular,
                                  distance_in_plane, fit_axis_bias_compensated, fit_axis_gamage_lasenby)
from calibration.captures import Capture, body_points
from calibration.fit_error import FitError
from calibration.joint_axis import JointAxisFit, fit_joint_axis_sara, joint_sign
from calibration.registration import invert, mean_pose
from rig.model import psm_kinematics as K


def _to_frame(T_m_W: np.ndarray, X: np.ndarray) -> np.ndarray:
    Ti = invert(T_m_W)
    return X @ Ti[:3, :3].T + Ti[:3, 3]


def _poses_in(T_m_W: np.ndarray, cap: Capture, body: str) -> tuple[np.ndarray, np.ndarray]:
    Ti = invert(T_m_W)
    R, p = cap.poses[body]
    return np.einsum("ij,kjl->kil", Ti[:3, :3], R), p @ Ti[:3, :3].T + Ti[:3, 3]


def reference_pose(cap: Capture, world_body: str) -> np.ndarray:
    """Mean pose (4x4) of the static world body over a phase (mocap frame)."""
    if world_body not in cap.poses or not cap.valid(world_body).any():
        raise FitError(f"the world body {world_body!r} was never seen in the {cap.name} phase; "
                       "check that it is in the cameras' view and named as in the tracker")
    T, _, _ = mean_pose(cap.matrices(world_body))
    return T


def fit_fixed_axis(cap: Capture, T_m_W: np.ndarray, body: str, joint: int, arm: str,
                   label: str) -> dict:
    """Plain and bias-compensated Gamage-Lasenby fits of `body` turning about an axis
    fixed in W, with the sign of the joint `joint` (1..3) of `arm`. Raises FitError."""
    X, source = body_points(cap, body)
    XW = _to_frame(T_m_W, X)
    fits = {}
    for name, fn in (("plain", fit_axis_gamage_lasenby), ("bias_compensated", fit_axis_bias_compensated)):
        try:
            fits[name] = fn(XW)
        except FitError as exc:
            raise FitError(f"{label} ({body} in the {cap.name} phase): {exc}", exc.condition) from None
    R, _ = _poses_in(T_m_W, cap, body)
    s = joint_sign(R, cap.joints[arm][:, joint - 1], fits["bias_compensated"].direction)
    for f in fits.values():
        if f.direction @ fits["bias_compensated"].direction * s < 0:
            f.direction = -f.direction
    return {"fits": fits, "source": source, "body": body}


def fit_passive_axis(cap: Capture, T_m_W: np.ndarray, body_a: str, body_b: str, label: str,
                     reference_direction_W: np.ndarray) -> tuple[JointAxisFit, tuple]:
    """SARA fit of the joint between two moving bodies; poses in W. Raises FitError."""
    Ra, pa = _poses_in(T_m_W, cap, body_a)
    Rb, pb = _poses_in(T_m_W, cap, body_b)
    ok = cap.valid(body_a) & cap.valid(body_b)
    if ok.any():
        k0 = int(np.flatnonzero(ok)[0])
        ref_a = Ra[k0].T @ reference_direction_W
    else:
        ref_a = None
    try:
        fit = fit_joint_axis_sara(Ra, pa, Rb, pb, reference_direction_a=ref_a)
    except FitError as exc:
        raise FitError(f"{label} ({body_a} - {body_b} in the {cap.name} phase): {exc}", exc.condition) from None
    return fit, (Ra, pa, Rb, pb, ok)


def _mean_distance_to_mapped(line_W: tuple[np.ndarray, np.ndarray], fit: JointAxisFit, R: np.ndarray,
                             p: np.ndarray, ok: np.ndarray, body: str) -> tuple[float, float]:
    """Mean over frames of the in-plane distance from a fixed line in W to a joint axis
    carried by a moving body's per-frame pose, and its standard error (m)."""
    P0, d0 = line_W
    d = []
    for k in np.flatnonzero(ok):
        P, n = fit.in_frame(R[k], p[k], body)
        d.append(distance_in_plane(P0, d0, P, n))
    d = np.array(d)
    cov = fit.point_cov_a if body == "a" else fit.point_cov_b
    # the axis point's own uncertainty moves every frame's distance together
    sys_std = float(np.sqrt(max(np.trace(cov), 0.0) / 2.0))
    return float(d.mean()), float(np.hypot(d.std(ddof=1) / np.sqrt(len(d)), sys_std))


def _line_distance_std(P1, n1, C1, P2, n2, C2) -> tuple[float, float]:
    """Distance in plane between two lines with point covariances C1, C2 (m)."""
    d0 = distance_in_plane(P1, n1, P2, n2)
    g = np.zeros(6)
    h = 1e-7
    for i in range(6):
        e = np.zeros(6)
        e[i] = h
        g[i] = (distance_in_plane(P1 + e[:3], n1, P2 + e[3:], n2)
                - distance_in_plane(P1 - e[:3], n1, P2 - e[3:], n2)) / (2 * h)
    C = np.zeros((6, 6))
    C[:3, :3], C[3:, 3:] = C1, C2
    return d0, float(np.sqrt(max(g @ C @ g, 0.0)))


def _axis_dict(fit: AxisFit | None, T_m_W: np.ndarray, point=None, direction=None, std=None) -> dict:
    """An axis in the mocap frame for result.json."""
    if fit is not None:
        point, direction, std = fit.point, fit.direction, (fit.direction_std, fit.point_std)
    P = T_m_W[:3, :3] @ point + T_m_W[:3, 3]
    n = T_m_W[:3, :3] @ direction
    return {"point": P.tolist(), "direction": n.tolist(), "direction_std_deg": float(np.rad2deg(std[0])),
            "point_std": float(std[1])}


def fit_link_lengths(q1: Capture, q2: Capture, q3: Capture, arm: str, bodies: dict[str, str],
                     world_body: str) -> dict:
    """Axes and lengths from the three phases (see the module docstring).

    Returns {"axes": {...} in the mocap frame of the q2 phase, "lengths": {name: {value,
    std}} m, "dh": {...}, "fits": per-axis fit details}. Raises FitError with what is
    missing when a phase does not support a fit.
    """
    W1, W2, W3 = (reference_pose(c, world_body) for c in (q1, q2, q3))
    # z1 (yaw) in the q1 phase's W; z2 and zR in the q2 phase's W (the same physical frame)
    ax1 = fit_fixed_axis(q1, W1, bodies["yaw"], 1, arm, "yaw axis z1")
    ax2 = fit_fixed_axis(q2, W2, bodies["back"], 2, arm, "pitch axis z2")
    axR = fit_fixed_axis(q2, W2, bodies["end"], 2, arm, "RCM pitch axis")
    z1 = ax1["fits"]["bias_compensated"]
    z2 = ax2["fits"]["bias_compensated"]
    zR = axR["fits"]["bias_compensated"]
    # passive joints: the back/bottom joint turns by -q2 (frame 4 = frame 3 turned by
    # -q2), the bottom/end joint by +q2; signs follow Table 4.3's thetas
    z3, (R3, p3, R4, p4, ok34) = fit_passive_axis(q2, W2, bodies["back"], bodies["bottom"],
                                                  "joint z3 (pitch back - pitch bottom)", -z2.direction)
    z4, (R4b, p4b, R5, p5, ok45) = fit_passive_axis(q2, W2, bodies["bottom"], bodies["end"],
                                                    "joint z4 (pitch bottom - pitch end)", z2.direction)

    lengths = {}
    lengths["l1"] = _mean_distance_to_mapped((z2.point, z2.direction), z3, R3, p3, ok34, "a")
    lengths["l2"] = _mean_distance_to_mapped((zR.point, zR.direction), z4, R5, p5, ok45, "b")
    # z3 and z4 are both fixed in the bottom link: compare them there (no per-frame noise)
    lengths["l3"] = _line_distance_std(z3.point_b, z3.direction_b, z3.point_cov_b,
                                       z4.point_a, z4.direction_a, z4.point_cov_a)
    lengths["l4"] = axis_distance(z2, zR, "plane")
    # l12: z1 (q1 phase) and z2 (q2 phase) in the same W (the world body is the same body)
    z2_in_1 = z2.transformed(*_relative(W1, W2))
    d12, _, _ = common_perpendicular(z1.point, z1.direction, z2_in_1.point, z2_in_1.direction)
    lengths["l12"] = (d12, float(np.hypot(z1.point_std, z2.point_std)))

    # insertion phase: RCM = foot on zR of the common perpendicular with z1, in W2
    z1_in_2 = z1.transformed(*_relative(W2, W1))
    _, _, rcm_W = common_perpendicular(z1_in_2.point, z1_in_2.direction, zR.point, zR.direction)
    u_W, u_info = insertion_direction(q3, W3, bodies["tool"], arm)
    u_W = _relative(W2, W3)[0] @ u_W
    # z4 at q2 = 0: the pitch end link is static in the q3 phase; map z4 with its mean pose
    T5, _, n5 = mean_pose(np.einsum("ij,kjl->kil", invert(W3), q3.matrices(bodies["end"])))
    if n5 == 0:
        raise FitError(f"the {bodies['end']} body was not seen in the insertion phase")
    T5 = invert(W2) @ W3 @ T5  # into the q2 phase's W
    P4 = T5[:3, :3] @ z4.point_b + T5[:3, 3]
    m = np.cross(zR.direction, u_W)
    m /= np.linalg.norm(m)
    l2p = float(abs((P4 - rcm_W) @ m))
    l2p_std = float(np.sqrt(max(m @ (T5[:3, :3] @ z4.point_cov_b @ T5[:3, :3].T) @ m, 0.0)
                            + zR.point_std ** 2 / 2))
    lengths["l2'"] = (l2p, l2p_std)

    dh = implied_dh(lengths)
    # everything reported in the mocap frame of the q2 phase
    axes = {
        "z1_yaw": _axis_dict(z1_in_2, W2),
        "z2_pitch": _axis_dict(z2, W2),
        "zR_rcm_pitch": _axis_dict(zR, W2),
        "z3": _axis_dict(None, W2, *_passive_at_zero(z3, R3, p3, ok34, q2, arm, "a", z2)),
        "z4": _axis_dict(None, W2, *_passive_at_zero(z4, R5, p5, ok45, q2, arm, "b", zR)),
        "insertion": {"point": (W2[:3, :3] @ rcm_W + W2[:3, 3]).tolist(),
                      "direction": (W2[:3, :3] @ u_W).tolist(), **u_info},
        "rcm": (W2[:3, :3] @ rcm_W + W2[:3, 3]).tolist(),
    }
    angles = {"z1_z2_deg": float(np.rad2deg(axis_angle(z1_in_2.direction, z2.direction))),
              "z2_zR_deg": float(np.rad2deg(axis_angle(z2.direction, zR.direction))),
              "insertion_z1_deg": float(np.rad2deg(axis_angle(u_W, z1_in_2.direction))),
              "insertion_z2_deg": float(np.rad2deg(axis_angle(u_W, z2.direction)))}
    fits = _fit_details(ax1, ax2, axR, z3, z4)
    # plain-fit lengths too, for the two distances that use only fixed axes
    plain = {"l4": axis_distance(ax2["fits"]["plain"], axR["fits"]["plain"], "plane")[0]}
    return {"lengths": {k: {"value": v[0], "std": v[1]} for k, v in lengths.items()},
            "lengths_plain_fit": plain, "dh": dh, "axes": axes, "angles": angles, "fits": fits,
            "_W2": W2}


def _fit_details(ax1: dict, ax2: dict, axR: dict, z3, z4) -> dict:
    """Per axis: each fit's spread and residual, and the plain fit against the
    bias-compensated one (fixed axes), or the SARA fit's (passive joints)."""
    fits = {}
    for key, ax in (("z1_yaw", ax1), ("z2_pitch", ax2), ("zR_rcm_pitch", axR)):
        fits[key] = {"body": ax["body"], "points": ax["source"]}
        for meth, f in ax["fits"].items():
            fits[key][meth] = {"direction_std_deg": float(np.rad2deg(f.direction_std)),
                               "point_std": f.point_std, "range_deg": float(np.rad2deg(f.range)),
                               "residual_rms": f.residual_rms, "noise_sigma": f.noise_sigma,
                               "eig_ratio": f.eig_ratio, "frames": f.n_frames}
        p_, b_ = ax["fits"]["plain"], ax["fits"]["bias_compensated"]
        fits[key]["plain_vs_compensated"] = {
            "direction_deg": float(np.rad2deg(axis_angle(p_.direction, b_.direction))),
            "point": float(distance_in_plane(p_.point, p_.direction, b_.point, b_.direction))}
    for key, f in (("z3", z3), ("z4", z4)):
        fits[key] = {"method": "SARA", "direction_std_deg": float(np.rad2deg(f.direction_std)),
                     "point_std": f.point_std, "range_deg": float(np.rad2deg(f.range)),
                     "residual_rms": f.residual_rms, "singular_ratio": f.singular_ratio,
                     "frames": f.n_frames}
    return fits


def _relative(Wa: np.ndarray, Wb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) mapping coordinates in frame Wb to frame Wa (both poses in the mocap frame)."""
    T = invert(Wa) @ Wb
    return T[:3, :3], T[:3, 3]


def _pose_at_zero(R: np.ndarray, p: np.ndarray, ok: np.ndarray, axis: AxisFit, q: np.ndarray) -> np.ndarray:
    """Mean pose (4x4, W) of a link at q2 = 0 from every frame of the sweep.

    The link turns about the fixed axis `axis` by the measured q2, so each frame's pose
    turned back about that axis by -q2 is a sample of the q2 = 0 pose; their mean has the
    marker noise of the whole sweep averaged out, not only of the frames near q2 = 0.
    """
    n, P = axis.direction, axis.point
    T = np.full((len(R), 4, 4), np.nan)
    for k in np.flatnonzero(ok):
        U = Rotation.from_rotvec(-q[k] * n).as_matrix()
        T[k] = np.eye(4)
        T[k, :3, :3] = U @ R[k]
        T[k, :3, 3] = U @ (p[k] - P) + P
    M, _, _ = mean_pose(T)
    return M


def _passive_at_zero(fit: JointAxisFit, R, p, ok, cap: Capture, arm: str, body: str, carrier: AxisFit):
    """A passive joint's axis (point, direction, stds) in W at q2 = 0."""
    T0 = _pose_at_zero(R, p, ok, carrier, cap.joints[arm][:, 1])
    P, d = fit.in_frame(T0[:3, :3], T0[:3, 3], body)
    return P, d, (fit.direction_std, fit.point_std)


def insertion_direction(cap: Capture, T_m_W: np.ndarray, tool_body: str, arm: str,
                        min_stroke: float = 0.01) -> tuple[np.ndarray, dict]:
    """Unit direction (in W) of increasing q3 from the tool body's motion, and its figures.

    Every tool point moves along a parallel line; the direction is the principal axis of
    the points' displacements from their own means, signed by the measured q3.
    """
    X, source = body_points(cap, tool_body)
    XW = _to_frame(T_m_W, X)
    ok = np.all(np.isfinite(XW.reshape(len(XW), -1)), axis=1)
    q3 = cap.joints[arm][:, 2]
    if ok.sum() < 20:
        raise FitError(f"insertion axis refused: too few frames with the {tool_body} body seen: "
                       f"{int(ok.sum())} (need at least 20)")
    stroke = float(np.ptp(q3[ok]))
    if stroke < min_stroke:
        raise FitError(f"insertion axis refused: too little range of motion: q3 moved {stroke * 1e3:.1f} mm "
                       f"(need at least {min_stroke * 1e3:.0f} mm)")
    D = (XW[ok] - XW[ok].mean(axis=0)).reshape(-1, 3)
    _, s, Vt = np.linalg.svd(D, full_matrices=False)
    u = Vt[0]
    disp = (XW[ok, 0] - XW[ok, 0].mean(axis=0)) @ u
    if np.cov(disp, q3[ok])[0, 1] < 0:
        u = -u
    # straightness: off-axis scatter relative to the stroke
    off = float(np.sqrt((s[1] ** 2 + s[2] ** 2) / D.shape[0]))
    direction_std = off / (stroke * np.sqrt(ok.sum() / 12.0))
    return u, {"stroke": stroke, "off_axis_rms": off, "direction_std_deg": float(np.rad2deg(direction_std)),
               "points": source}


def implied_dh(lengths: dict[str, tuple[float, float]]) -> dict:
    """a3, a4 (inverse-variance means), beta and a5 with a6 from Table 4.3 (m, rad)."""
    def ivw(a, b):
        (va, sa), (vb, sb) = a, b
        wa, wb = 1 / max(sa, 1e-9) ** 2, 1 / max(sb, 1e-9) ** 2
        return (wa * va + wb * vb) / (wa + wb), 1 / math.sqrt(wa + wb)

    a3, s3 = ivw(lengths["l1"], lengths["l2"])
    a4, s4 = ivw(lengths["l3"], lengths["l4"])
    l2p, s2p = lengths["l2'"]
    x = min(max(l2p / a3, -1.0), 1.0)
    beta = math.asin(x)
    sb = math.hypot(s2p / a3, l2p * s3 / a3 ** 2) / max(math.sqrt(1 - x * x), 1e-9)
    a5 = (a3 * math.sin(beta) + K.A6) / math.cos(beta)
    da5_db = (a3 + K.A6 * math.sin(beta)) / math.cos(beta) ** 2
    da5_da3 = math.tan(beta)
    s5 = math.hypot(da5_db * sb, da5_da3 * s3)
    return {"a3": {"value": a3, "std": s3}, "a4": {"value": a4, "std": s4},
            "beta": {"value": beta, "std": sb}, "a5": {"value": a5, "std": s5,
                                                       "note": "with a6 = -0.043 m from Table 4.3"}}


# ----------------------------------------------------------------------------- truth
