"""Axis of rotation from marker trajectories (thesis appendix A.1, section 4.1.1).

Markers of a body rotating about one joint axis relative to a reference body, expressed
in the reference body's frame (`calibration.registration.to_frame`), sweep circles in
parallel planes. Gamage & Lasenby (2002) give closed-form least squares for both parts:

* direction n: minimise sum_p sum_k [(v_k^p - m^p) . n]^2 (eq. A.1). With
  A = sum_p (mean_k v v^T - vbar vbar^T) (eq. A.5), n is the eigenvector of A with the
  smallest eigenvalue.
* centre m: minimise sum_p sum_k (|v_k^p - m|^2 - r_p^2)^2 (eq. A.6), which is linear:
  A m = b, b = 1/2 sum_p (mean_k v |v|^2 - vbar mean_k |v|^2). For a single axis A is
  singular along n, so m is solved in the plane perpendicular to n.

The plain estimate is biased by marker noise: E[A] gains sigma^2 (1 - 1/N) I per marker
and E[b] gains sigma^2 (1 - 1/N) vbar, which matters when the arcs are short (small
range of motion) because A's in-plane eigenvalues are then small. Halvorsen (2005)
subtracts both terms ("bias compensated least squares"); for an ideal hinge the
out-of-plane eigenvalue of A is exactly that noise term, so sigma^2 is estimated from
it unless given. `fit_axis_bias_compensated` does this.

Every fit reports residuals, an uncertainty (direction covariance from the eigenvector
perturbation, centre covariance from the Jacobian of the geometric circle residuals)
and its condition (angular range, eigenvalue ratio, frames and occlusions), and refuses
with a FitError below thresholds. Units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter
from scipy.spatial.transform import Rotation

from calibration.fit_error import FitError
from calibration.registration import rigid_body_poses

DEFAULT_MIN_RANGE = np.deg2rad(10.0)
DEFAULT_MIN_FRAMES = 20
DEFAULT_MAX_OCCLUDED = 0.5
# Out-of-plane over smallest in-plane eigenvalue of A: near 0 for a clean hinge, near 1
# when the markers' motion does not define a plane (no rotation, or noise dominates).
DEFAULT_MAX_EIG_RATIO = 0.1


@dataclass
class AxisFit:
    """A fitted axis of rotation, in the frame the markers were given in.

    direction: unit (3,); point: (3,) m, the point of the axis at the axial level of the
    markers' centroid; radii: (P,) m, the markers' circle radii; residual_rms: m, RMS of
    the per-sample radial and axial residuals (not an accuracy: see the covariances);
    direction_cov: (3, 3) rad^2 covariance of the direction (rank 2, perpendicular to it);
    point_cov: (3, 3) m^2 covariance of the point (in the plane perpendicular to the axis);
    range: rad, angle swept about the axis; eig_ratio: see DEFAULT_MAX_EIG_RATIO;
    noise_sigma: m, the marker noise the fit saw (estimated from the out-of-plane scatter).
    """

    direction: np.ndarray
    point: np.ndarray
    radii: np.ndarray
    residual_rms: float
    radial_rms: float
    axial_rms: float
    direction_cov: np.ndarray
    point_cov: np.ndarray
    range: float
    eig_ratio: float
    eigenvalues: np.ndarray
    noise_sigma: float
    n_frames: int
    n_markers: int
    occluded_fraction: float
    method: str
    condition: dict = field(default_factory=dict)

    @property
    def direction_std(self) -> float:
        """RMS angular uncertainty of the direction (rad)."""
        return float(np.sqrt(max(np.trace(self.direction_cov), 0.0)))

    @property
    def point_std(self) -> float:
        """RMS position uncertainty of the point, perpendicular to the axis (m)."""
        return float(np.sqrt(max(np.trace(self.point_cov), 0.0)))

    def transformed(self, R: np.ndarray, p: np.ndarray) -> "AxisFit":
        """The same axis expressed in another frame (x' = R x + p); covariances rotate."""
        import dataclasses
        return dataclasses.replace(self, direction=R @ self.direction, point=R @ self.point + p,
                                   direction_cov=R @ self.direction_cov @ R.T,
                                   point_cov=R @ self.point_cov @ R.T)


def _as_markers(markers: np.ndarray) -> np.ndarray:
    X = np.asarray(markers, dtype=float)
    if X.ndim == 2 and X.shape[1] == 3:
        X = X[:, None, :]
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"markers must be (N frames, P markers, 3), got {np.shape(markers)}")
    return X


def _swept_range(X: np.ndarray, vis: np.ndarray, n: np.ndarray, centre: np.ndarray,
                 U: np.ndarray) -> float:
    """Angle swept about n (rad), from the marker set's rotation when >= 3 markers are
    seen together (independent of the fitted centre), else from the markers' angles
    about the fitted centre."""
    full = vis.all(axis=1)
    if X.shape[1] >= 3 and full.sum() >= 2:
        R, _, ok = rigid_body_poses(X[full])
        rel = np.einsum("kij,lj->kil", R, R[0])  # R_k R_0^T: rotation since the first frame
        theta = Rotation.from_matrix(rel).as_rotvec() @ n
        # a 5-frame running median keeps single noisy frames from widening max - min
        theta = median_filter(np.unwrap(theta), size=min(5, len(theta)), mode="nearest")
        return float(theta.max() - theta.min())
    ranges = []
    for p in range(X.shape[1]):
        v = X[vis[:, p], p] - centre
        if len(v) < 2:
            continue
        xy = v @ U
        ang = median_filter(np.unwrap(np.arctan2(xy[:, 1], xy[:, 0])), size=min(5, len(xy)),
                            mode="nearest")
        ranges.append(ang.max() - ang.min())
    return float(np.median(ranges)) if ranges else 0.0


def _fit(markers: np.ndarray, *, compensate: bool, noise_sigma: float | None,
         min_range: float, min_frames: int, max_occluded_fraction: float,
         max_eig_ratio: float, reference_direction: np.ndarray | None) -> AxisFit:
    X = _as_markers(markers)
    N, P, _ = X.shape
    vis = np.all(np.isfinite(X), axis=2)
    counts = vis.sum(axis=0)
    occluded = 1.0 - counts / max(N, 1)
    cond: dict = {"frames": int(N), "markers": int(P),
                  "visible_per_marker": counts.tolist(),
                  "occluded_fraction": float(occluded.mean()) if P else 1.0}
    problems = []
    if N < min_frames:
        problems.append(f"too few frames: {N} (need at least {min_frames})")
    if P and occluded.mean() > max_occluded_fraction:
        per = ", ".join(f"marker {p}: {100 * o:.0f}%" for p, o in enumerate(occluded))
        problems.append(f"too many occluded frames: {100 * occluded.mean():.0f}% of marker "
                        f"samples missing (limit {100 * max_occluded_fraction:.0f}%; {per})")
    use = counts >= max(min_frames, 3)
    if N >= min_frames and not use.any():
        problems.append(f"too few frames: no marker is visible in {min_frames} frames")
    if problems:
        raise FitError("axis fit refused: " + "; ".join(problems), cond)

    Xu, visu = X[:, use], vis[:, use]
    Pu = int(use.sum())
    c = np.nanmean(Xu.reshape(-1, 3)[visu.reshape(-1)], axis=0)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    M = np.zeros((3, 3))  # sum_p C_p / n_p, for the direction covariance
    s_bias = 0.0
    vbar_w = np.zeros(3)  # sum_p (1 - 1/n_p) vbar_p, the b bias direction
    vbars, samples = [], []
    for p in range(Pu):
        v = Xu[visu[:, p], p] - c
        n_p = len(v)
        vbar = v.mean(axis=0)
        C = v.T @ v / n_p - np.outer(vbar, vbar)
        sq = np.einsum("ki,ki->k", v, v)
        A += C
        M += C / n_p
        b += 0.5 * ((v * sq[:, None]).mean(axis=0) - vbar * sq.mean())
        s_bias += 1.0 - 1.0 / n_p
        vbar_w += (1.0 - 1.0 / n_p) * vbar
        vbars.append(vbar)
        samples.append(v)

    lam, E = np.linalg.eigh(A)
    n = E[:, 0]
    U = E[:, 1:]  # in-plane basis
    eig_ratio = float(lam[0] / lam[1]) if lam[1] > 0 else np.inf
    # sigma^2 (1 - 1/n) summed over markers is the expected out-of-plane eigenvalue
    sigma2 = float(noise_sigma ** 2) if noise_sigma is not None else max(lam[0], 0.0) / s_bias
    A2 = U.T @ A @ U
    b2 = U.T @ b
    if compensate:
        A2 = A2 - sigma2 * s_bias * np.eye(2)
        b2 = b2 - sigma2 * (U.T @ vbar_w)
    try:
        m2 = np.linalg.solve(A2, b2)
    except np.linalg.LinAlgError:
        raise FitError("axis fit refused: the centre equations are singular (no in-plane "
                       "spread of the markers)", cond) from None
    point = c + U @ m2

    if reference_direction is not None:
        if n @ np.asarray(reference_direction, float) < 0:
            n = -n
    elif n[np.argmax(np.abs(n))] < 0:
        n = -n  # a reproducible sign; the physical sense needs a reference direction

    # Residuals: radial (in-plane distance to the circle) and axial (off the marker's plane)
    radii, rad_res, ax_res, J_rows = [], [], [], []
    for p, v in enumerate(samples):
        xy = v @ U - m2
        d = np.linalg.norm(xy, axis=1)
        r = d.mean()
        radii.append(r)
        rad_res.append(d - r)
        ax_res.append((v - vbars[p]) @ n)
        Jp = np.zeros((len(v), 2 + Pu))
        Jp[:, :2] = -xy / d[:, None]
        Jp[:, 2 + p] = -1.0
        J_rows.append(Jp)
    rad_res = np.concatenate(rad_res)
    ax_res = np.concatenate(ax_res)
    n_samples = len(rad_res)
    radial_rms = float(np.sqrt(np.mean(rad_res ** 2)))
    axial_rms = float(np.sqrt(np.mean(ax_res ** 2)))

    # Direction: tilt along in-plane eigenvector e_j has variance e_j^T (s^2 A^-1 M A^-1) e_j
    s2_ax = float(np.sum(ax_res ** 2) / max(n_samples - Pu, 1))
    Ainv = U @ np.diag(1.0 / lam[1:]) @ U.T
    direction_cov = s2_ax * Ainv @ M @ Ainv
    # Centre: Gauss-Newton covariance of the geometric circle fit (centre, radii)
    J = np.vstack(J_rows)
    s2_rad = float(np.sum(rad_res ** 2) / max(n_samples - 2 - Pu, 1))
    C_geo = s2_rad * np.linalg.pinv(J.T @ J)
    point_cov = U @ C_geo[:2, :2] @ U.T

    rng = _swept_range(Xu, visu, n, point, U)
    cond.update({"range_deg": float(np.rad2deg(rng)), "eig_ratio": eig_ratio,
                 "eigenvalues": lam.tolist(), "markers_used": Pu})
    problems = []
    if rng < min_range:
        problems.append(f"too little range of motion: {np.rad2deg(rng):.2f} deg swept about the "
                        f"axis (need at least {np.rad2deg(min_range):.1f} deg); sweep the joint further")
    if eig_ratio > max_eig_ratio:
        problems.append(f"the markers do not move in planes about one axis: eigenvalue ratio "
                        f"{eig_ratio:.3f} (limit {max_eig_ratio:.3f}); too little motion for the "
                        "noise, or not a single rotation")
    if problems:
        raise FitError("axis fit refused: " + "; ".join(problems), cond)

    return AxisFit(direction=n, point=point, radii=np.array(radii),
                   residual_rms=float(np.sqrt(radial_rms ** 2 + axial_rms ** 2)),
                   radial_rms=radial_rms, axial_rms=axial_rms, direction_cov=direction_cov,
                   point_cov=point_cov, range=rng, eig_ratio=eig_ratio, eigenvalues=lam,
                   noise_sigma=float(np.sqrt(sigma2)), n_frames=int(N), n_markers=Pu,
                   occluded_fraction=cond["occluded_fraction"],
                   method="bias-compensated Gamage-Lasenby" if compensate else "Gamage-Lasenby",
                   condition=cond)


def fit_axis_gamage_lasenby(markers: np.ndarray, *, min_range: float = DEFAULT_MIN_RANGE,
                            min_frames: int = DEFAULT_MIN_FRAMES,
                            max_occluded_fraction: float = DEFAULT_MAX_OCCLUDED,
                            max_eig_ratio: float = DEFAULT_MAX_EIG_RATIO,
                            reference_direction: np.ndarray | None = None) -> AxisFit:
    """Gamage-Lasenby axis fit (appendix A.1, eqs. A.1-A.7).

    markers: (N frames, P markers, 3) m in the reference body's frame, NaN where
    occluded ((N, 3) for one marker). min_range: rad. reference_direction: flips the
    returned direction to point along it (e.g. the nominal joint axis).
    Raises FitError when the range, frames, occlusions or eigenvalue ratio fail.
    """
    return _fit(markers, compensate=False, noise_sigma=None, min_range=min_range,
                min_frames=min_frames, max_occluded_fraction=max_occluded_fraction,
                max_eig_ratio=max_eig_ratio, reference_direction=reference_direction)


def fit_axis_bias_compensated(markers: np.ndarray, *, noise_sigma: float | None = None,
                              min_range: float = DEFAULT_MIN_RANGE,
                              min_frames: int = DEFAULT_MIN_FRAMES,
                              max_occluded_fraction: float = DEFAULT_MAX_OCCLUDED,
                              max_eig_ratio: float = DEFAULT_MAX_EIG_RATIO,
                              reference_direction: np.ndarray | None = None) -> AxisFit:
    """Gamage-Lasenby with Halvorsen's bias compensation of the centre.

    noise_sigma: m, the marker noise standard deviation if known; by default it is
    estimated from the out-of-plane scatter. Other arguments as fit_axis_gamage_lasenby.
    """
    return _fit(markers, compensate=True, noise_sigma=noise_sigma, min_range=min_range,
                min_frames=min_frames, max_occluded_fraction=max_occluded_fraction,
                max_eig_ratio=max_eig_ratio, reference_direction=reference_direction)


def fit_axis(markers: np.ndarray, method: str = "bias_compensated", **kwargs) -> AxisFit:
    """Axis fit by name: "bias_compensated" (default) or "gamage_lasenby"."""
    if method == "bias_compensated":
        return fit_axis_bias_compensated(markers, **kwargs)
    if method == "gamage_lasenby":
        return fit_axis_gamage_lasenby(markers, **kwargs)
    raise ValueError(f"unknown axis fit method {method!r}; use 'bias_compensated' or 'gamage_lasenby'")


# ------------------------------------------------------------------ distances between axes

def axis_angle(d1: np.ndarray, d2: np.ndarray) -> float:
    """Angle between two axes (rad, in [0, pi/2]): an axis has no sign."""
    d1 = np.asarray(d1, float) / np.linalg.norm(d1)
    d2 = np.asarray(d2, float) / np.linalg.norm(d2)
    return float(np.arctan2(np.linalg.norm(np.cross(d1, d2)), abs(d1 @ d2)))


def common_perpendicular(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray
                         ) -> tuple[float, np.ndarray, np.ndarray]:
    """Shortest distance (m) between two lines and its feet on each line.

    Lines x = p_i + s d_i. For parallel lines (|d1 x d2| < 1e-12) the feet are p1 and the
    foot of p1 on line 2.
    """
    p1, d1, p2, d2 = (np.asarray(x, float) for x in (p1, d1, p2, d2))
    d1 = d1 / np.linalg.norm(d1)
    d2 = d2 / np.linalg.norm(d2)
    w = p1 - p2
    b = d1 @ d2
    denom = 1.0 - b * b
    if denom < 1e-12:
        f1 = p1
        f2 = p2 + (w @ d2) * d2
    else:
        s = (b * (w @ d2) - (w @ d1)) / denom
        t = ((w @ d2) - b * (w @ d1)) / denom
        f1 = p1 + s * d1
        f2 = p2 + t * d2
    return float(np.linalg.norm(f1 - f2)), f1, f2


def distance_in_plane(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray,
                      at: np.ndarray | None = None) -> float:
    """Distance (m) between two near-parallel axes measured in a plane perpendicular to
    them (thesis 4.1.1): the plane's normal is their mean direction, it passes through
    `at` (default: midway between p1 and p2), and the distance is between the axes'
    intersections with it. For parallel axes this equals the common perpendicular; for
    slightly skew ones it is the link length at the place the plane is put.
    """
    p1, d1, p2, d2 = (np.asarray(x, float) for x in (p1, d1, p2, d2))
    d1 = d1 / np.linalg.norm(d1)
    d2 = d2 / np.linalg.norm(d2)
    if d1 @ d2 < 0:
        d2 = -d2
    nrm = d1 + d2
    nrm /= np.linalg.norm(nrm)
    at = (p1 + p2) / 2 if at is None else np.asarray(at, float)
    x1 = p1 + ((at - p1) @ nrm) / (d1 @ nrm) * d1
    x2 = p2 + ((at - p2) @ nrm) / (d2 @ nrm) * d2
    return float(np.linalg.norm(x1 - x2))


def axis_distance(fit1: AxisFit, fit2: AxisFit, kind: str = "plane",
                  at: np.ndarray | None = None) -> tuple[float, float]:
    """Distance between two fitted axes (m) and its standard deviation (m).

    kind: "plane" (distance_in_plane, for near-parallel axes) or "perpendicular"
    (common_perpendicular). The uncertainty is first-order propagation of both fits'
    direction and point covariances (taken as independent).
    """
    if kind == "plane":
        def f(x):
            return distance_in_plane(x[0:3], x[3:6], x[6:9], x[9:12], at)
    elif kind == "perpendicular":
        def f(x):
            return common_perpendicular(x[0:3], x[3:6], x[6:9], x[9:12])[0]
    else:
        raise ValueError(f"kind must be 'plane' or 'perpendicular', got {kind!r}")
    x0 = np.concatenate([fit1.point, fit1.direction, fit2.point, fit2.direction])
    C = np.zeros((12, 12))
    C[0:3, 0:3], C[3:6, 3:6] = fit1.point_cov, fit1.direction_cov
    C[6:9, 6:9], C[9:12, 9:12] = fit2.point_cov, fit2.direction_cov
    d0 = f(x0)
    h = 1e-7
    g = np.zeros(12)
    for i in range(12):
        e = np.zeros(12)
        e[i] = h
        g[i] = (f(x0 + e) - f(x0 - e)) / (2 * h)
    return d0, float(np.sqrt(max(g @ C @ g, 0.0)))
