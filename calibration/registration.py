"""Rigid registration: point sets (Kabsch/Horn by SVD), marker bodies, arm-to-arm bases.

Pure mathematics: arms, kinematics and mocap are passed in as arrays. Transforms are
4x4 homogeneous matrices or (rotation (3, 3), translation (3,) m) pairs; `T_a_b` maps
coordinates in frame b to frame a (x_a = R x_b + t). Uncertainties are 6x6 covariances
of (small rotation about the target frame's x, y, z [rad], translation [m]).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.fit_error import FitError


@dataclass
class RigidTransformFit:
    """A fitted rigid transform target = R source + t, with its quality.

    residual_rms: m (RMS of per-point residuals, or of per-sample scatter for poses);
    cov: 6x6 covariance of (rotation small angle [rad], translation [m]); condition:
    measured figures (spread of the points in m, counts).
    """

    rotation: np.ndarray
    translation: np.ndarray
    residual_rms: float
    residuals: np.ndarray
    cov: np.ndarray
    n: int
    method: str
    condition: dict = field(default_factory=dict)

    def matrix(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation
        return T

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) points from the source frame to the target frame (m)."""
        return np.asarray(points) @ self.rotation.T + self.translation

    @property
    def rotation_std(self) -> float:
        """RMS rotation uncertainty (rad): sqrt(trace of the rotation covariance)."""
        return float(np.sqrt(max(np.trace(self.cov[:3, :3]), 0.0)))

    @property
    def translation_std(self) -> float:
        """RMS translation uncertainty (m): sqrt(trace of the translation covariance)."""
        return float(np.sqrt(max(np.trace(self.cov[3:, 3:]), 0.0)))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3)."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    s = np.linalg.norm(np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                                 R[..., 1, 0] - R[..., 0, 1]], axis=-1), axis=-1) / 2.0
    return np.arctan2(s, c)  # atan2 keeps precision at small and near-pi angles


def project_to_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation matrices (Frobenius) to (..., 3, 3) matrices, det = +1."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(M.shape[:-2] + (3, 3))
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    return U @ D @ Vt


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error rad) between two 4x4 transforms."""
    dt = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    dr = float(rotation_angle(T_est[:3, :3].T @ T_true[:3, :3]))
    return dt, dr


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of 4x4 rigid transforms (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _kabsch_core(src: np.ndarray, dst: np.ndarray, w: np.ndarray):
    """Weighted Kabsch on (n, 3) arrays: R, t minimising sum w |R src + t - dst|^2."""
    ws = w / w.sum()
    cs = ws @ src
    cd = ws @ dst
    H = (src - cs).T @ ((dst - cd) * ws[:, None])
    U, _, Vt = np.linalg.svd(H)
    # det fix: a reflection is the best orthogonal fit for noisy near-planar sets
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cd - R @ cs


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
           *, min_points: int = 3, min_spread: float = 1e-3, method: str = "kabsch"
           ) -> RigidTransformFit:
    """Rigid transform (Kabsch/Horn by SVD, det fix) with target ~= R source + t.

    source, target: (N, 3) corresponding points (m); rows with NaN are left out.
    min_spread: m, the RMS extent of the points along their second principal direction
    must reach it, otherwise the rotation about the points' line is undetermined.
    Uncertainty: cov = s^2 (J^T J)^-1 with J the Jacobian of the residuals in
    (small rotation, translation) and s^2 = SSR / (3N - 6).
    """
    a = np.asarray(source, dtype=float)
    b = np.asarray(target, dtype=float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"source and target must both be (N, 3), got {a.shape} and {b.shape}")
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=float)
    ok &= np.isfinite(w) & (w > 0)
    a, b, w = a[ok], b[ok], w[ok]
    n = len(a)
    cond = {"n_points": int(n), "n_rejected": int((~ok).sum())}
    if n < max(min_points, 3):
        raise FitError(f"rigid registration refused: {n} usable point pairs, need at least "
                       f"{max(min_points, 3)} (non-collinear)", cond)
    sv = np.linalg.svd(a - a.mean(axis=0), compute_uv=False) / np.sqrt(n)
    cond["spread"] = sv.tolist()
    if sv[1] < min_spread:
        raise FitError(f"rigid registration refused: the points are nearly collinear (RMS "
                       f"spread {sv[1] * 1e3:.3f} mm across their line, need "
                       f"{min_spread * 1e3:.3f} mm); use points that span a plane or volume", cond)
    R, t = _kabsch_core(a, b, w)
    res = a @ R.T + t - b
    rn = np.linalg.norm(res, axis=1)
    Ra = a @ R.T
    J = np.zeros((3 * n, 6))
    for i in range(n):
        J[3 * i:3 * i + 3, :3] = -skew(Ra[i])
        J[3 * i:3 * i + 3, 3:] = np.eye(3)
    dof = 3 * n - 6
    s2 = float((res ** 2).sum() / dof) if dof > 0 else np.nan
    cov = s2 * np.linalg.pinv(J.T @ J)
    return RigidTransformFit(rotation=R, translation=t, residual_rms=float(np.sqrt(np.mean(rn ** 2))),
                             residuals=rn, cov=cov, n=n, method=method, condition=cond)


def rigid_body_poses(markers: np.ndarray, template: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame pose of a marker body, as a mocap system computes it.

    markers: (N, P, 3) m, NaN where occluded; template: (P, 3) marker positions in the
    body frame (default: the first frame with every marker, centred on their centroid).
    Returns R (N, 3, 3), p (N, 3) (body frame -> mocap frame) and valid (N,): frames
    with fewer than 3 markers are invalid and NaN.
    """
    X = np.asarray(markers, dtype=float)
    N, P, _ = X.shape
    vis = np.all(np.isfinite(X), axis=2)
    if template is None:
        full = np.flatnonzero(vis.all(axis=1))
        if full.size == 0:
            raise FitError("no frame shows every marker of the body: cannot define its template")
        template = X[full[0]] - X[full[0]].mean(axis=0)
    template = np.asarray(template, dtype=float)
    R = np.full((N, 3, 3), np.nan)
    p = np.full((N, 3), np.nan)
    valid = vis.sum(axis=1) >= 3
    # Frames with all markers are solved in one batch; partial frames one by one.
    full = valid & vis.all(axis=1)
    if np.any(full):
        A = template - template.mean(axis=0)
        B = X[full]
        cb = B.mean(axis=1)
        H = np.einsum("pi,kpj->kij", A, B - cb[:, None, :])
        U, _, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
        D = np.zeros((len(d), 3, 3))
        D[:, 0, 0] = D[:, 1, 1] = 1.0
        D[:, 2, 2] = d
        Rk = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)
        R[full] = Rk
        p[full] = cb - np.einsum("kij,j->ki", Rk, template.mean(axis=0))
    for k in np.flatnonzero(valid & ~full):
        m = vis[k]
        Rk, tk = _kabsch_core(template[m], X[k, m], np.ones(m.sum()))
        R[k], p[k] = Rk, tk
    return R, p, valid


def to_frame(points: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Express world points (N, P, 3) in per-frame body frames (R (N, 3, 3), p (N, 3)).

    This turns markers of a moving body into coordinates relative to another (possibly
    moving) reference body: x_ref = R^T (x_world - p). NaN propagates.
    """
    X = np.asarray(points, dtype=float)
    return np.einsum("kji,kpj->kpi", R, X - p[:, None, :])


def to_static_reference(points: np.ndarray, ref_markers: np.ndarray, ref_template: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Express world points (N, P, 3) in a reference body that did not move.

    The reference pose is the mean of its per-frame poses (from ref_markers (N, Q, 3)
    and its template (Q, 3)), so its marker noise averages out instead of entering every
    frame as rotation noise times the lever arm; that keeps the relative marker noise
    isotropic, which the bias-compensated axis fit assumes. Returns the points in the
    reference frame and the mean reference pose (4, 4).
    """
    R, p, valid = rigid_body_poses(ref_markers, ref_template)
    Ts = np.tile(np.eye(4), (len(R), 1, 1))
    Ts[:, :3, :3], Ts[:, :3, 3] = R, p
    Ts[~valid] = np.nan
    T, _, _ = mean_pose(Ts)
    n = len(points)
    return to_frame(points, np.broadcast_to(T[:3, :3], (n, 3, 3)),
                    np.broadcast_to(T[:3, 3], (n, 3))), T


def register_from_touch_points(tips_1: np.ndarray, tips_2: np.ndarray, *,
                               min_points: int = 4, min_spread: float = 0.01
                               ) -> RigidTransformFit:
    """Base-to-base transform T_1_2 (PSM2 base -> PSM1 base) from common touched points.

    tips_1, tips_2: (N, 3) m, each arm's tool tip from its own forward kinematics in its
    own base frame while both touch the same N physical points. Returns the fit with
    tips_1 ~= R tips_2 + t. min_spread: m, see `kabsch` (default 10 mm).
    """
    return kabsch(tips_2, tips_1, min_points=min_points, min_spread=min_spread,
                  method="touch points")


def mean_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean (4x4) of pose samples (N, 4, 4) (NaN samples ignored), the 6x6 covariance
    of that mean (rotation small angle about the mocap axes [rad], translation [m]),
    and the number of samples used.
    """
    T = np.asarray(T, dtype=float)
    if T.ndim == 2:
        T = T[None]
    ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    T = T[ok]
    n = len(T)
    if n == 0:
        raise FitError("no valid pose sample (every sample occluded)")
    R = project_to_rotation(T[:, :3, :3].mean(axis=0))  # chordal L2 mean
    t = T[:, :3, 3].mean(axis=0)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    if n > 1:
        dth = Rotation.from_matrix(T[:, :3, :3] @ R.T).as_rotvec()  # left (mocap-frame) errors
        e = np.hstack([dth, T[:, :3, 3] - t])
        cov = np.cov(e.T) / n
    else:
        cov = np.full((6, 6), np.nan)
    return out, cov, n


def _perturb(T: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Left-perturb a 4x4 transform by (small rotation, translation)."""
    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec(d[:3]).as_matrix()
    E[:3, 3] = d[3:]
    return E @ T


def _error_coords(T: np.ndarray, T0: np.ndarray) -> np.ndarray:
    """(rotation vector, translation) of T relative to T0, rotation left in T0's target."""
    return np.hstack([Rotation.from_matrix(T[:3, :3] @ T0[:3, :3].T).as_rotvec(),
                      T[:3, 3] - T0[:3, 3]])


def propagate_cov(f: Callable[[np.ndarray], np.ndarray], n_in: int, cov_in: np.ndarray,
                  h: float = 1e-7) -> np.ndarray:
    """First-order covariance of f(d) at d = 0 for input covariance cov_in (central
    differences, step h)."""
    J = np.zeros((len(f(np.zeros(n_in))), n_in))
    for i in range(n_in):
        e = np.zeros(n_in)
        e[i] = h
        J[:, i] = (f(e) - f(-e)) / (2 * h)
    return J @ cov_in @ J.T


def register_from_mocap(T_mocap_body1: np.ndarray, T_mocap_body2: np.ndarray,
                        T_body1_base1: np.ndarray | None = None,
                        T_body2_base2: np.ndarray | None = None) -> RigidTransformFit:
    """Base-to-base transform T_1_2 (PSM2 base -> PSM1 base) from mocap.

    T_mocap_body1/2: (4, 4) or (N, 4, 4) poses of a body fixed to each arm's base (or its
    RCM frame) measured in the mocap frame; NaN samples (occluded) are skipped.
    T_body*_base*: the fixed body-to-base offset of each arm (identity when the body
    frame is the base frame, e.g. an RCM frame from pivot calibration).
    Returns T_1_2 = (T_m_b1 T_b1_base1)^-1 (T_m_b2 T_b2_base2) with its covariance
    propagated from the scatter of the samples (standard error of the mean).
    """
    A, covA, nA = mean_pose(T_mocap_body1)
    B, covB, nB = mean_pose(T_mocap_body2)
    O1 = np.eye(4) if T_body1_base1 is None else np.asarray(T_body1_base1, float)
    O2 = np.eye(4) if T_body2_base2 is None else np.asarray(T_body2_base2, float)
    T = invert(A @ O1) @ (B @ O2)

    def f(d: np.ndarray) -> np.ndarray:
        return _error_coords(invert(_perturb(A, d[:6]) @ O1) @ (_perturb(B, d[6:]) @ O2), T)

    cov_in = np.zeros((12, 12))
    cov_in[:6, :6] = np.nan_to_num(covA)
    cov_in[6:, 6:] = np.nan_to_num(covB)
    cov = propagate_cov(f, 12, cov_in)
    if nA < 2 or nB < 2:
        cov[:] = np.nan  # one sample: no scatter, no uncertainty estimate
    scatter = []
    for Ts, M in ((T_mocap_body1, A), (T_mocap_body2, B)):
        Ts = np.asarray(Ts, float).reshape(-1, 4, 4)
        ok = np.all(np.isfinite(Ts.reshape(len(Ts), -1)), axis=1)
        scatter.append(np.linalg.norm(Ts[ok, :3, 3] - M[:3, 3], axis=1))
    res = np.concatenate(scatter)
    return RigidTransformFit(rotation=T[:3, :3], translation=T[:3, 3],
                             residual_rms=float(np.sqrt(np.mean(res ** 2))), residuals=res,
                             cov=cov, n=min(nA, nB), method="mocap",
                             condition={"samples_1": nA, "samples_2": nB})
