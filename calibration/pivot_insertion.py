"""Pivot calibration of a tool body whose insertion moves a little (appendix A.2, extended).

Eq. A.9 assumes the tool body's offset to the RCM, b_tip, is constant. On a PSM the tool
body rides on the insertion stage, so b_tip shifts by (q3 - q3_ref) along the insertion
axis whenever the held insertion sags or sticks (millimetres under gravity and stiction
while q1 and q2 sweep). With the measured q3 that shift is linear in one more unknown,
v (the body-frame insertion direction per metre of q3):

    R_k (b_tip + d_k v) + p_k = b_post,    d_k = q3_k - q3_ref

so [R_k | d_k R_k | -I] [b_tip; v; b_post] = -p_k is still one linear least squares. With
q3 truly constant (d_k = 0) the v column vanishes and this is eq. A.10 exactly.

Units: m. Returns a calibration.pivot.PivotFit (b_tip at q3_ref).
"""

from __future__ import annotations

import numpy as np

from calibration.fit_error import FitError
from calibration.pivot import DEFAULT_MIN_FRAMES, PivotFit, rotation_range

# Below this spread of q3 (m) v is not determined: the fit falls back to eq. A.10.
MIN_INSERTION_SPREAD = 5e-5


def _solve(R, p, d, use_v):
    N = len(R)
    cols = [R.reshape(3 * N, 3)]
    if use_v:
        cols.append((R * d[:, None, None]).reshape(3 * N, 3))
    cols.append(-np.tile(np.eye(3), (N, 1)))
    A = np.hstack(cols)
    x, *_ = np.linalg.lstsq(A, -p.reshape(-1), rcond=None)
    tip, post = x[:3], x[-3:]
    v = x[3:6] if use_v else np.zeros(3)
    return A, tip, v, post


def pivot_with_insertion(R: np.ndarray, p: np.ndarray, q3: np.ndarray, *, q3_ref: float | None = None,
                         reject: float = 0.003, min_frames: int = DEFAULT_MIN_FRAMES,
                         min_rotation_range: float = np.deg2rad(10.0)) -> tuple[PivotFit, np.ndarray]:
    """One-step pivot calibration with the insertion shift (see the module docstring).

    R (N, 3, 3), p (N, 3) m: tool body poses in the mocap frame (NaN where occluded);
    q3 (N,) m: measured insertion at the frames; q3_ref: m (default: the median).
    Frames whose residual exceeds `reject` m after a first fit are dropped and the fit
    repeated (one robust pass). Returns the fit and v (3,), the body-frame shift of b_tip
    per metre of q3 (about minus the insertion axis when determined).
    """
    R = np.asarray(R, float)
    p = np.asarray(p, float)
    q3 = np.asarray(q3, float)
    ok = np.all(np.isfinite(R.reshape(len(R), -1)), axis=1) & np.all(np.isfinite(p), axis=1) & np.isfinite(q3)
    n_ok = int(ok.sum())
    cond = {"frames": int(len(R)), "frames_usable": n_ok}
    if n_ok < min_frames:
        raise FitError(f"pivot calibration refused: too few frames: {n_ok} usable of {len(R)} "
                       f"(need at least {min_frames}; occluded frames are not usable)", cond)
    rng = rotation_range(R[ok])
    cond["rotation_range"] = rng
    if rng < min_rotation_range:
        raise FitError(f"pivot calibration refused: too little rotation: {np.rad2deg(rng):.2f} deg between "
                       f"the most different poses (need at least {np.rad2deg(min_rotation_range):.1f} deg); "
                       "sweep q1 and q2 further", cond)
    ref = float(np.median(q3[ok])) if q3_ref is None else float(q3_ref)
    d = q3 - ref
    use_v = float(np.std(d[ok])) > MIN_INSERTION_SPREAD
    used = ok.copy()
    for _ in range(2):
        A, tip, v, post = _solve(R[used], p[used], d[used], use_v)
        pts = np.einsum("kij,kj->ki", R[ok], tip + d[ok, None] * v) + p[ok]
        e = np.linalg.norm(pts - post, axis=1)
        used = np.zeros(len(R), bool)
        used[np.flatnonzero(ok)[e < reject]] = True
        if used.sum() < min_frames:
            raise FitError(f"pivot calibration refused: only {int(used.sum())} frames within "
                           f"{reject * 1e3:.1f} mm of one pivot point", cond)
    A, tip, v, post = _solve(R[used], p[used], d[used], use_v)
    points = np.full((len(R), 3), np.nan)
    points[used] = np.einsum("kij,kj->ki", R[used], tip + d[used, None] * v) + p[used]
    dev = points[used] - post
    rms_xyz = np.sqrt(np.mean(dev ** 2, axis=0))
    dof = max(3 * int(used.sum()) - A.shape[1], 1)
    cov = float(np.sum(dev ** 2) / dof) * np.linalg.pinv(A.T @ A)
    cond.update({"frames_used": int(used.sum()), "frames_rejected": int(ok.sum() - used.sum()),
                 "q3_ref": ref, "q3_spread": float(np.ptp(q3[ok])), "insertion_term": bool(use_v),
                 "singular_value": float(np.sqrt(max(1.0 - np.linalg.svd(R[used].mean(axis=0), compute_uv=False)[0], 0.0)))})
    fit = PivotFit(tip=tip, post=post, points=points, rms_xyz=rms_xyz, rms=float(np.sqrt(np.sum(rms_xyz ** 2))),
                   tip_cov=cov[:3, :3], post_cov=cov[-3:, -3:], inliers=used,
                   method="one-step + insertion" if use_v else "one-step", condition=cond)
    return fit, v
