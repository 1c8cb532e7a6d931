"""`rig link-lengths`: joint axes and link lengths of a PSM from motion capture (thesis 4.1.1, A.1).

Marker bodies (three markers each) sit on the yaw link, the pitch back link, the pitch
bottom link, the pitch end link and the tool, plus one on the table ("world"). The arm
sweeps q1 over its range with q2 = 0, then q2 with q1 = 0 (thesis 4.1.1), then a short
insertion stroke of q3 with q1 = q2 = 0 to locate the tool axis. Every joint state and
mocap frame goes to the run's MCAP.

Frames of reference. Each phase is expressed in the world body's frame W, its pose
averaged over the phase (`mean_pose`), so its marker noise does not enter the fits. During
the q2 sweep the yaw link is static too, so W is a static reference for every axis fixed
to the yaw link.

Axes (all in W; a direction's sign is the joint's positive sense, from the measured joints):

* z1, the yaw axis: the yaw body's markers during the q1 sweep (Gamage-Lasenby, A.1);
* z2, the pitch axis: the pitch back body during the q2 sweep (Gamage-Lasenby);
* zR, the RCM pitch axis: the pitch end body turns about a line through the remote
  centre of motion parallel to z2 as q2 sweeps (Gamage-Lasenby);
* z3, the joint between the pitch back and pitch bottom links, and z4, the joint between
  the pitch bottom and pitch end links: both links move, so these come from the two
  bodies' poses together (SARA, `calibration.joint_axis`);
* the insertion axis: the direction the tool body moves along during the q3 stroke,
  through the RCM (the point of zR nearest z1).

Each axis fixed to the yaw link is fitted twice, plain Gamage-Lasenby and with
Halvorsen's bias compensation; both are reported, the compensated one is used.

Link lengths (Figure 4.2a is not in the text available to this project, so the Table 4.1
names are defined here on the model's parallelogram O2-O3-O4-RCM, where O2..O4 are the
joint axes z2..z4 of Table 4.3 and every distance is measured in a plane perpendicular to
the (parallel) axes, `calibration.axis_fit.distance_in_plane`):

* l1  = |z2 - z3|, the pitch back link (crank): DH a3 = 0.150 m;
* l2  = |zR - z4|, the pitch end link between the bottom link and the RCM line, the
        parallelogram's second crank: a3 in the model;
* l3  = |z3 - z4|, the pitch bottom link: DH a4 = 0.516 m;
* l4  = |z2 - zR|, the side of the parallelogram on the yaw link, from the pitch axis to
        the RCM: a4 in the model;
* l12 = the common perpendicular between the yaw axis z1 and the pitch axis z2: 0 in the
        model (they intersect, Table 4.3 a2 = 0); it measures how far the RCM can be off
        the yaw axis;
* l2' = the offset of the insertion axis from z4 at q2 = 0, perpendicular to both the
        insertion axis and the pitch axes: a3 sin(beta) = 0.141 m in the model.

The DH lengths they imply: a3 = inverse-variance mean of l1 and l2, a4 = that of l3 and
l4, beta = asin(l2' / a3) and, keeping Table 4.3's a6 = -0.043 m (the tool offset the
rotations cannot see), a5 = (a3 sin(beta) + a6) / cos(beta) from the exact-RCM condition
(rig.model.psm_kinematics). Every value carries a one-sigma uncertainty propagated from the
fits. Units: m and rad (degrees only in printed text).
"""

from __future__ import annotations

import math
import sys

import click
import numpy as np
from scipy.spatial.transform import Rotation

from calibration.axis_fit import (AxisFit, axis_angle, axis_distance, common_perpendicular,
                                  distance_in_plane, fit_axis_bias_compensated, fit_axis_gamage_lasenby)
from calibration.captures import Capture, body_points
from calibration.fit_error import FitError
from calibration.joint_axis import JointAxisFit, fit_joint_axis_sara, joint_sign
from calibration.registration import invert, mean_pose
from procedures.mocap_capture import Collector, move_capture, open_devices, settle, tracker_stats
from rig.commands.abort import exit_on_abort
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context, json_option, yes_option
from rig.commands.parameters import Parameter, with_parameters
from rig.commands.report import emit_result, exit_for_status
from rig.model import psm_kinematics as K
from rig.runs import provenance
from rig.runs.run import Run

PROCEDURE = "link-lengths"
STEPS = (
    "power on and home the arm",
    "sweep q1 with q2 = 0",
    "sweep q2 with q1 = 0",
    "stroke q3 with q1 = q2 = 0",
    "fit the joint axes",
    "compute the link lengths",
    "save the result and plot",
)

PARAMETERS = [
    Parameter("arm", "PSM1", "", "Arm to measure", type=str),
    Parameter("q1_range", float(K.Q_MAX[0]), "rad", "Sweep q1 over +/- this (the full range by default)",
              minimum=0.0, maximum=float(K.Q_MAX[0])),
    Parameter("q2_range", float(K.Q_MAX[1]), "rad", "Sweep q2 over +/- this (the full range by default)",
              minimum=0.0, maximum=float(K.Q_MAX[1])),
    Parameter("q3", 0.12, "m", "Insertion held during the q1 and q2 sweeps", minimum=0.02, maximum=0.24),
    Parameter("q3_stroke", 0.10, "m", "Insertion stroke of the q3 phase (from --q3 outwards)",
              minimum=0.0, maximum=0.2),
    Parameter("passes", 2, "", "Sweeps back and forth of q2 (the passive joints' fits average over them; "
              "q1 sweeps once)", minimum=1, maximum=10, type=int),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
]

BODY_SUFFIXES = {"yaw": "yaw", "back": "pitch_back", "bottom": "pitch_bottom", "end": "pitch_end",
                 "tool": "tool"}


def nominal_lengths() -> dict[str, float]:
    """Table 4.1 quantities of the model (rig.model.psm_kinematics, Table 4.3 completed), m."""
    return {"l1": K.A3, "l2": K.A3, "l12": 0.0, "l2'": K.A3 * math.sin(K.BETA), "l3": K.A4, "l4": K.A4}


def nominal_dh() -> dict[str, float]:
    return {"a3": K.A3, "a4": K.A4, "a5": K.A5, "beta": K.BETA}


# ----------------------------------------------------------------------------- fitting

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

def true_geometry(world, arm: str, q3: float) -> dict:
    """The simulated arm's true axes and Table 4.1 quantities (world = mocap frame)."""
    base = world.arms[arm].spec.base
    T = {k: base @ v for k, v in K.frames(np.array([0.0, 0.0, q3])).items()}

    def line(f):
        return T[f][:3, 3], T[f][:3, 2]

    rcm = world.rcm_world(arm)
    P1, n1 = line("1")
    P2, n2 = line("2")
    P3, n3 = line("3")
    P4, n4 = line("4")
    u = T["6"][:3, 2]
    m = np.cross(n2, u)
    m /= np.linalg.norm(m)
    lengths = {"l1": distance_in_plane(P2, n2, P3, n3), "l2": distance_in_plane(rcm, n2, P4, n4),
               "l3": distance_in_plane(P3, n3, P4, n4), "l4": distance_in_plane(P2, n2, rcm, n2),
               "l12": common_perpendicular(P1, n1, P2, n2)[0], "l2'": float(abs((P4 - rcm) @ m))}
    axes = {"z1_yaw": n1, "z2_pitch": n2, "zR_rcm_pitch": n2, "z3": n3, "z4": n4, "insertion": u}
    return {"lengths": lengths, "axes": axes, "rcm": rcm}


def compare_truth(result: dict, truth: dict) -> dict:
    """Errors against the simulated truth: lengths (m), axis directions (deg), RCM (m)."""
    out = {"lengths": {k: result["lengths"][k]["value"] - v for k, v in truth["lengths"].items()},
           "axes_deg": {}}
    for k, n in truth["axes"].items():
        d = np.array(result["axes"][k]["direction"])
        # signs are the joints' senses: compare signed where the model's z is the positive
        # sense, unsigned for the passive joints whose z is by convention
        out["axes_deg"][k] = float(np.rad2deg(axis_angle(d, n)))
    out["rcm"] = float(np.linalg.norm(np.array(result["axes"]["rcm"]) - truth["rcm"]))
    return out


# ----------------------------------------------------------------------------- report

def report_table(result: dict) -> str:
    nom = result["nominal"]["lengths"]
    truth = result.get("truth", {}).get("lengths")
    lines = ["Table 4.1 quantities (m):",
             f"  {'':5} {'fitted':>10} {'+-':>8} {'nominal':>9}" + (f" {'truth':>9} {'error':>9}" if truth else "")]
    for k in ("l1", "l2", "l12", "l2'", "l3", "l4"):
        v = result["lengths"][k]
        row = f"  {k:5} {v['value']:10.5f} {v['std']:8.5f} {nom[k]:9.5f}"
        if truth:
            row += f" {truth[k]:9.5f} {(v['value'] - truth[k]) * 1e3:+8.3f}mm"
        lines.append(row)
    lines.append("DH lengths implied:")
    for k in ("a3", "a4", "a5", "beta"):
        v = result["dh"][k]
        unit = "rad" if k == "beta" else "m"
        lines.append(f"  {k:5} {v['value']:10.5f} {v['std']:8.5f} {result['nominal']['dh'][k]:9.5f} {unit}")
    if "truth" in result:
        err = result["truth"]["errors"]
        worst = max(err["axes_deg"].items(), key=lambda kv: kv[1])
        lines.append(f"simulated truth: worst length error {max(abs(e) for e in err['lengths'].values()) * 1e3:.3f} mm, "
                     f"worst axis direction error {worst[1]:.4f} deg ({worst[0]}), RCM {err['rcm'] * 1e3:.3f} mm")
    return "\n".join(lines)


def plot(result: dict, q1: Capture, q2: Capture, bodies: dict, path) -> None:
    """Pitch-plane picture: marker traces of the q2 sweep and the fitted axes, plus the
    fitted-minus-nominal lengths with their uncertainties."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array(result["axes"]["z2_pitch"]["direction"])
    rcm = np.array(result["axes"]["rcm"])
    u = np.array(result["axes"]["insertion"]["direction"])
    e1 = u - (u @ n) * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)

    def proj(X):
        return np.stack([(X - rcm) @ e1, (X - rcm) @ e2], axis=-1)

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.5))
    for key, b in bodies.items():
        if b in q2.poses:
            X, _ = body_points(q2, b)
            P = proj(X.reshape(-1, 3))
            ax.plot(P[:, 0], P[:, 1], ".", ms=1, label=b)
    for key, mk in (("z2_pitch", "o"), ("zR_rcm_pitch", "s"), ("z3", "^"), ("z4", "v")):
        P = proj(np.array(result["axes"][key]["point"]))
        ax.plot(P[0], P[1], "k" + mk, ms=8)
        ax.annotate(key, P, textcoords="offset points", xytext=(6, 6))
    ax.plot([0, 0.25], [0, 0], "k--", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("along the insertion axis at q2 = 0 (m)")
    ax.set_ylabel("in the pitch plane (m)")
    ax.set_title("q2 sweep: marker traces and fitted axes (pitch plane)")
    ax.legend(fontsize=7, markerscale=6)
    names = ["l1", "l2", "l12", "l2'", "l3", "l4"]
    ref = result.get("truth", {}).get("lengths") or result["nominal"]["lengths"]
    vals = [(result["lengths"][k]["value"] - ref[k]) * 1e3 for k in names]
    errs = [result["lengths"][k]["std"] * 1e3 for k in names]
    bx.errorbar(range(len(names)), vals, yerr=errs, fmt="o", capsize=4)
    bx.axhline(0, color="k", lw=0.8)
    for lim in (-0.3, 0.3):
        bx.axhline(lim, color="r", lw=0.6, ls=":")
    bx.set_xticks(range(len(names)), names)
    bx.set_ylabel("fitted - " + ("truth" if "truth" in result else "nominal") + " (mm)")
    bx.set_title("Table 4.1 quantities (1-sigma bars; dotted: 0.3 mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- procedure

def _symmetric_sweep(joint: int, span: float, passes: int, q3: float) -> list[np.ndarray]:
    goals = []
    for _ in range(passes):
        for s in (-1.0, 1.0):
            q = np.array([0.0, 0.0, q3])
            q[joint] = s * span
            goals.append(q)
    goals.append(np.array([0.0, 0.0, q3]))
    return goals


#: m: one-sigma uncertainty of a Table 4.1 length above which the fit has not measured it:
#: the thesis reports its lengths to the millimetre, and a sound sweep with sub-millimetre
#: marker noise gives a few tenths of a millimetre (bench_calibration_procedures).
LENGTH_STD_BOUND = 0.002


def missed_bound(result: dict) -> str | None:
    """Why the fitted lengths are not usable (an uncertainty not finite or above the
    bound), or None."""
    import math

    high = [f"{k} +-{v['std'] * 1e3:.2f} mm" if v.get("std") is not None and math.isfinite(v["std"]) else f"{k} (no std)"
            for k, v in result["lengths"].items()
            if not (v.get("std") is not None and math.isfinite(v["value"]) and v["std"] <= LENGTH_STD_BOUND)]
    if not high:
        return None
    return (f"length uncertainty {', '.join(high)} above {LENGTH_STD_BOUND * 1e3:g} mm: check the marker bodies' "
            "tracking (occlusion, loose bodies) and sweep again")


def run_link_lengths(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """The procedure as a function (the CLI and the bench call it). Returns the result."""
    arm_name = parameters["arm"]
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    if arm_name not in cfg.arms:
        raise InputError(f"no arm {arm_name!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    dev = open_devices(cfg, seed=seed, arms=[arm_name])
    bodies = {k: f"{arm_name}_{v}" for k, v in BODY_SUFFIXES.items()}
    world_body = "world"
    q3h = parameters["q3"]
    try:
        with Run(PROCEDURE, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=list(STEPS),
                 root=run_root, progress=progress) as run:
            arm = run.claim(dev.arms[arm_name])
            all_bodies = list(bodies.values()) + [world_body]
            with run.step(STEPS[0]):
                dev.person.confirm(f"Mount the marker bodies {', '.join(all_bodies)} and clear the "
                                   f"workspace of {arm_name}")
                dev.person.detach_object()
                arm.power_on()
                home = Collector("home", all_bodies)
                move_capture(dev, run, arm, [np.array([0.0, 0.0, q3h])], home)
            phases = {}
            for idx, (joint, span) in ((1, (0, parameters["q1_range"])), (2, (1, parameters["q2_range"]))):
                goals = _symmetric_sweep(joint, span, parameters["passes"] if joint == 1 else 1, q3h)
                col = Collector(f"q{joint + 1} sweep", all_bodies)
                with run.step(STEPS[idx], total=len(goals)) as st:
                    move_capture(dev, run, arm, goals, col, step=st)
                    settle(dev, run, col, [arm], 0.2)
                phases[joint] = col.capture()
            col = Collector("q3 stroke", all_bodies)
            # three strokes: the insertion direction's noise falls with the frames on it
            goals = [np.array([0.0, 0.0, q3h + f * parameters["q3_stroke"]]) for f in (1, 0) * 3]
            with run.step(STEPS[3], total=len(goals)) as st:
                move_capture(dev, run, arm, goals, col, step=st)
            phases[2] = col.capture()
            with run.step(STEPS[4]):
                fitted = fit_link_lengths(phases[0], phases[1], phases[2], arm_name, bodies, world_body)
            with run.step(STEPS[5]):
                result = {"arm": arm_name, **fitted,
                          "nominal": {"lengths": nominal_lengths(), "dh": nominal_dh()},
                          "frames": {c.name: c.n for c in phases.values()},
                          "bodies": bodies, "world_body": world_body,
                          "tracker": tracker_stats(dev.tracker)}
                if dev.world is not None:
                    truth = true_geometry(dev.world, arm_name, q3h)
                    result["truth"] = {"lengths": truth["lengths"],
                                       "errors": compare_truth(result, truth)}
            with run.step(STEPS[6]):
                plot(result, phases[0], phases[1], bodies, run.dir / "link_lengths.png")
                result.pop("_W2", None)
                result["plot"] = str(run.dir / "link_lengths.png")
                result["summary"] = {k: v["value"] for k, v in result["lengths"].items()}
                result["provenance"] = provenance.live(cfg, [arm_name], run.dir)
                missed = missed_bound(result)
                run.finish(result, "failed" if missed else "completed", missed)
    finally:
        dev.close()
    return run.result


@click.command(name=PROCEDURE)
@with_parameters(PARAMETERS)
@click.option("--steps", "list_steps", is_flag=True, help="List the steps and exit without moving anything.")
@yes_option
@json_option
@click.pass_context
@exit_on_abort
def command(ctx, parameters, list_steps: bool, as_json: bool) -> None:
    """Joint axes and link lengths of a PSM from motion capture (thesis 4.1.1, A.1).

    Sweeps q1 (q2 = 0), q2 (q1 = 0) and a q3 stroke, fits each joint axis between pairs
    of marker bodies (Gamage-Lasenby plain and bias-compensated, SARA for the
    parallelogram's passive joints) and reports Table 4.1's l1, l2, l12, l2', l3, l4 and
    the DH lengths they imply, in m with 1-sigma uncertainties. Saves result.json and
    link_lengths.png in the run folder.
    """
    if list_steps:
        for i, s in enumerate(STEPS, 1):
            click.echo(f"{i}. {s}")
        return
    cfg = config_from_context(ctx)
    try:
        result = run_link_lengths(cfg, parameters)
    except FitError as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: refused: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report_table(result) + f"\nrun folder: {result['run_dir']}")
    exit_for_status(PROCEDURE, result)
