"""Pivot calibration: the remote centre of motion from tracked tool poses (appendix A.2).

A body on the tool (or on the link that carries it) pivots about the RCM. At every
frame k its pose in the mocap frame is (R_k, p_k) and a constant vector b_tip (body
frame, from the body origin to the RCM) maps to a constant point b_post (mocap frame,
the RCM): b_post = R_k b_tip + p_k (eq. A.9). Stacking gives the algebraic one-step
least squares of eq. A.10, [R_k | -I][b_tip; b_post] = -p_k. Yaniv (2015) compares this
with a two-step method (eliminate b_post by subtracting the means) and with a sphere fit
to the body origins; all three are here, with RANSAC rejection of outlier frames.

The quality figures follow Table 6.1: the per-frame RCM estimates R_k b_tip + p_k
scatter about b_post; their RMS per axis (x, y, z) is reported, in metres here (the
table prints mm). The fit refuses (FitError) when the rotations do not determine the
point: too few frames, too little rotation range, or rotations about one axis only
(then the RCM along that axis is undetermined and the stacked matrix is singular).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from calibration.fit_error import FitError

DEFAULT_MIN_FRAMES = 20
DEFAULT_MIN_ROTATION_RANGE = np.deg2rad(10.0)
# sigma_min([R_k | -I]) / sqrt(N) = sqrt(1 - s_max(mean R_k)): 0 for rotations about a
# single axis, ~0.1 for +/-10 deg about two perpendicular axes, ~0.5 for the PSM sweeps.
DEFAULT_MIN_SINGULAR_VALUE = 0.02


@dataclass
class PivotFit:
    """Result of a pivot calibration. All lengths in m.

    tip: b_tip, body origin -> RCM in the body frame; post: b_post, the RCM in the mocap
    frame; points: (N, 3) per-frame RCM estimates R_k b_tip + p_k (NaN for frames not
    used); rms_xyz: RMS of points - post per axis over the used frames (Table 6.1);
    rms: 3-D RMS; tip_cov, post_cov: (3, 3) m^2; inliers: (N,) frames used;
    condition: rotation range (rad), normalised smallest singular value, counts.
    """

    tip: np.ndarray
    post: np.ndarray
    points: np.ndarray
    rms_xyz: np.ndarray
    rms: float
    tip_cov: np.ndarray
    post_cov: np.ndarray
    inliers: np.ndarray
    method: str
    condition: dict = field(default_factory=dict)

    @property
    def post_std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.post_cov), 0, None))

    @property
    def tip_std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.tip_cov), 0, None))

    def summary(self) -> dict:
        """The result fields procedures print with --json (m)."""
        return {"rcm": self.post.tolist(), "tip_offset": self.tip.tolist(), "rms": self.rms,
                "rms_xyz": self.rms_xyz.tolist(), "rcm_std": self.post_std.tolist(),
                "tip_offset_std": self.tip_std.tolist(), "method": self.method,
                "frames_used": int(self.inliers.sum()), "frames": int(len(self.inliers)),
                "rotation_range_deg": float(np.rad2deg(self.condition.get("rotation_range", np.nan))),
                "singular_value": self.condition.get("singular_value")}


def _check_inputs(R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or p.shape != (len(R), 3):
        raise ValueError(f"rotations must be (N, 3, 3) and positions (N, 3), got {R.shape} and {p.shape}")
    ok = np.all(np.isfinite(R.reshape(len(R), -1)), axis=1) & np.all(np.isfinite(p), axis=1)
    return R, p, ok


def rotation_range(R: np.ndarray, max_frames: int = 400) -> float:
    """Largest rotation angle (rad) between any two of the rotations (N, 3, 3).

    Pairwise on at most `max_frames` evenly spaced frames (O(n^2)).
    """
    if len(R) < 2:
        return 0.0
    idx = np.linspace(0, len(R) - 1, min(len(R), max_frames)).round().astype(int)
    S = R[idx]
    tr = np.einsum("kij,lij->kl", S, S)  # trace(R_k^T R_l)
    return float(np.arccos(np.clip((tr.min() - 1.0) / 2.0, -1.0, 1.0)))  # min trace = max angle


def _stacked(R: np.ndarray) -> np.ndarray:
    N = len(R)
    A = np.zeros((3 * N, 6))
    A[:, :3] = R.reshape(3 * N, 3)
    A[:, 3:] = -np.tile(np.eye(3), (N, 1))
    return A


def _condition(R: np.ndarray, n_total: int, n_used: int, min_frames: int,
               min_rotation_range: float, min_singular_value: float) -> dict:
    cond = {"frames": int(n_total), "frames_used": int(n_used),
            "frames_rejected": int(n_total - n_used)}
    problems = []
    if n_used < min_frames:
        problems.append(f"too few frames: {n_used} usable of {n_total} (need at least {min_frames}; "
                        "occluded frames are not usable)")
        raise FitError("pivot calibration refused: " + "; ".join(problems), cond)
    rng = rotation_range(R)
    # sigma_min of the stacked matrix from the 6x6 normal matrix (cheap for long sweeps)
    Rbar = R.mean(axis=0)
    smax = np.linalg.svd(Rbar, compute_uv=False)[0]
    sv = float(np.sqrt(max(1.0 - smax, 0.0)))
    cond.update({"rotation_range": rng, "singular_value": sv})
    if rng < min_rotation_range:
        problems.append(f"too little rotation: {np.rad2deg(rng):.2f} deg between the most different "
                        f"poses (need at least {np.rad2deg(min_rotation_range):.1f} deg); sweep q1 and q2 further")
    if sv < min_singular_value:
        problems.append(f"the stacked [R_k | -I] matrix is nearly singular (normalised smallest "
                        f"singular value {sv:.4f} < {min_singular_value}): the rotations are about "
                        "one axis only, so the RCM along it is undetermined; sweep both q1 and q2")
    if problems:
        raise FitError("pivot calibration refused: " + "; ".join(problems), cond)
    return cond


def _finish(R: np.ndarray, p: np.ndarray, used: np.ndarray, tip: np.ndarray, post: np.ndarray,
            method: str, cond: dict) -> PivotFit:
    """Per-frame RCM points, Table 6.1 RMS and the one-step covariance at (tip, post)."""
    pts = np.full((len(R), 3), np.nan)
    pts[used] = np.einsum("kij,j->ki", R[used], tip) + p[used]
    d = pts[used] - post
    rms_xyz = np.sqrt(np.mean(d ** 2, axis=0))
    n = int(used.sum())
    A = _stacked(R[used])
    dof = 3 * n - 6
    s2 = float(np.sum(d ** 2) / dof) if dof > 0 else np.nan
    cov = s2 * np.linalg.pinv(A.T @ A)
    return PivotFit(tip=tip, post=post, points=pts, rms_xyz=rms_xyz,
                    rms=float(np.sqrt(np.sum(rms_xyz ** 2))), tip_cov=cov[:3, :3],
                    post_cov=cov[3:, 3:], inliers=used.copy(), method=method, condition=cond)


def _solve_one_step(R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, *_ = np.linalg.lstsq(_stacked(R), -p.reshape(-1), rcond=None)
    return x[:3], x[3:]


def pivot_one_step(R: np.ndarray, p: np.ndarray, *, min_frames: int = DEFAULT_MIN_FRAMES,
                   min_rotation_range: float = DEFAULT_MIN_ROTATION_RANGE,
                   min_singular_value: float = DEFAULT_MIN_SINGULAR_VALUE,
                   _used: np.ndarray | None = None) -> PivotFit:
    """Algebraic one-step pivot calibration, eq. A.10.

    R: (N, 3, 3) body rotations and p: (N, 3) body positions (m) in the mocap frame;
    NaN frames (occluded) are skipped. min_rotation_range: rad.
    """
    R, p, ok = _check_inputs(R, p)
    used = ok if _used is None else ok & _used
    cond = _condition(R[used], len(R), int(used.sum()), min_frames, min_rotation_range,
                      min_singular_value)
    tip, post = _solve_one_step(R[used], p[used])
    return _finish(R, p, used, tip, post, "one-step", cond)


def pivot_two_step(R: np.ndarray, p: np.ndarray, *, min_frames: int = DEFAULT_MIN_FRAMES,
                   min_rotation_range: float = DEFAULT_MIN_ROTATION_RANGE,
                   min_singular_value: float = DEFAULT_MIN_SINGULAR_VALUE,
                   _used: np.ndarray | None = None) -> PivotFit:
    """Two-step pivot calibration: (R_k - mean R) b_tip = -(p_k - mean p) for b_tip,
    then b_post = mean_k (R_k b_tip + p_k). Arguments as pivot_one_step."""
    R, p, ok = _check_inputs(R, p)
    used = ok if _used is None else ok & _used
    cond = _condition(R[used], len(R), int(used.sum()), min_frames, min_rotation_range,
                      min_singular_value)
    Ru, pu = R[used], p[used]
    D = (Ru - Ru.mean(axis=0)).reshape(-1, 3)
    tip, *_ = np.linalg.lstsq(D, -(pu - pu.mean(axis=0)).reshape(-1), rcond=None)
    post = (np.einsum("kij,j->ki", Ru, tip) + pu).mean(axis=0)
    return _finish(R, p, used, tip, post, "two-step", cond)


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Sphere (centre (3,) m, radius m) through points (N, 3): algebraic fit refined by
    geometric least squares (distances to the surface)."""
    P = np.asarray(points, dtype=float)
    c0 = P.mean(axis=0)
    Q = P - c0  # centred for conditioning
    A = np.hstack([2 * Q, np.ones((len(Q), 1))])
    x, *_ = np.linalg.lstsq(A, np.einsum("ki,ki->k", Q, Q), rcond=None)
    c = x[:3]
    r = float(np.sqrt(max(x[3] + c @ c, 0.0)))
    sol = least_squares(lambda z: np.linalg.norm(Q - z[:3], axis=1) - z[3],
                        np.r_[c, r], method="lm")
    return sol.x[:3] + c0, float(sol.x[3])


def pivot_sphere(R: np.ndarray, p: np.ndarray, *, min_frames: int = DEFAULT_MIN_FRAMES,
                 min_rotation_range: float = DEFAULT_MIN_ROTATION_RANGE,
                 min_singular_value: float = DEFAULT_MIN_SINGULAR_VALUE,
                 _used: np.ndarray | None = None) -> PivotFit:
    """Sphere-fit pivot calibration: the body origins p_k lie on a sphere about the RCM;
    its centre is b_post and b_tip = mean_k R_k^T (b_post - p_k). Needs the body origin
    away from the RCM. Arguments as pivot_one_step."""
    R, p, ok = _check_inputs(R, p)
    used = ok if _used is None else ok & _used
    cond = _condition(R[used], len(R), int(used.sum()), min_frames, min_rotation_range,
                      min_singular_value)
    post, radius = fit_sphere(p[used])
    tip = np.einsum("kji,kj->ki", R[used], post - p[used]).mean(axis=0)
    cond["sphere_radius"] = radius
    return _finish(R, p, used, tip, post, "sphere", cond)


METHODS = {"one_step": pivot_one_step, "two_step": pivot_two_step, "sphere": pivot_sphere}


def pivot_ransac(R: np.ndarray, p: np.ndarray, *, method: str = "one_step",
                 threshold: float = 0.003, iterations: int = 300, seed: int = 0,
                 sample_size: int = 3, min_inlier_fraction: float = 0.5,
                 **fit_kwargs) -> PivotFit:
    """Pivot calibration with RANSAC rejection of outlier frames (e.g. marker swaps).

    Random minimal samples of `sample_size` frames (seeded by `seed`) give candidate
    (b_tip, b_post); a frame is an inlier when |R_k b_tip + p_k - b_post| < threshold (m).
    The best candidate's inliers are refitted with `method` ("one_step", "two_step",
    "sphere"), inliers recomputed once, and refitted again. FitError if fewer than
    min_inlier_fraction of the usable frames agree.
    """
    if method not in METHODS:
        raise ValueError(f"unknown pivot method {method!r}; use one of {list(METHODS)}")
    R, p, ok = _check_inputs(R, p)
    idx = np.flatnonzero(ok)
    if len(idx) < max(sample_size, fit_kwargs.get("min_frames", DEFAULT_MIN_FRAMES)):
        raise FitError(f"pivot calibration refused: too few frames: {len(idx)} usable of {len(R)}",
                       {"frames": len(R), "frames_used": len(idx)})
    rng = np.random.default_rng(seed)
    Rv, pv = R[idx], p[idx]
    best, best_key = None, None
    for _ in range(iterations):
        s = rng.choice(len(idx), size=sample_size, replace=False)
        A = _stacked(Rv[s])
        if np.linalg.svd(A, compute_uv=False)[-1] < 1e-3:
            continue  # near-identical rotations: the sample does not fix a point
        x, *_ = np.linalg.lstsq(A, -pv[s].reshape(-1), rcond=None)
        e = np.linalg.norm(np.einsum("kij,j->ki", Rv, x[:3]) + pv - x[3:], axis=1)
        inl = e < threshold
        key = (int(inl.sum()), -float(np.median(e)))
        if best_key is None or key > best_key:
            best, best_key = inl, key
    if best is None or best.sum() < min_inlier_fraction * len(idx):
        n_in = 0 if best is None else int(best.sum())
        raise FitError(f"pivot calibration refused: only {n_in} of {len(idx)} frames agree on one "
                       f"pivot point within {threshold * 1e3:.2f} mm (need "
                       f"{100 * min_inlier_fraction:.0f}%)", {"frames": len(R), "inliers": n_in})
    fit = METHODS[method]
    used = np.zeros(len(R), bool)
    used[idx[best]] = True
    result = fit(R, p, _used=used, **fit_kwargs)
    e = np.linalg.norm(np.einsum("kij,j->ki", Rv, result.tip) + pv - result.post, axis=1)
    used = np.zeros(len(R), bool)
    used[idx[e < threshold]] = True
    result = fit(R, p, _used=used, **fit_kwargs)
    result.method += " + RANSAC"
    result.condition.update({"ransac_threshold": threshold, "ransac_seed": seed,
                             "outliers": int(len(idx) - used.sum())})
    return result


def fit_pivot(R: np.ndarray, p: np.ndarray, method: str = "one_step", ransac: bool = False,
              **kwargs) -> PivotFit:
    """Pivot calibration by name: method "one_step" (eq. A.10), "two_step" or "sphere",
    optionally with RANSAC (kwargs go to pivot_ransac / the method)."""
    if method not in METHODS:
        raise ValueError(f"unknown pivot method {method!r}; use one of {list(METHODS)}")
    if ransac:
        return pivot_ransac(R, p, method=method, **kwargs)
    return METHODS[method](R, p, **kwargs)
