"""The axis of a joint between two moving bodies from their poses (SARA).

The passive joints of the PSM's parallelogram connect two links that both move while q2
sweeps, so neither is a static reference. Expressing one body's markers in the other's
per-frame pose puts that pose's rotation noise, times the lever arm to the markers, into
every sample (the 0.27 deg case of the axis-fit notes). The symmetrical axis of rotation
approach (Ehrig et al. 2007, "A survey of formal methods for determining functional joint
axes") uses both poses in one linear least squares instead:

    for every frame k and every point c on the axis:  R_a,k c_a + p_a,k = R_b,k c_b + p_b,k

with c_a, c_b the same axis point in body a's and body b's frame. Stacking
M = [R_a,k | -R_b,k] (3N x 6), y = p_b,k - p_a,k, the hinge makes M rank 5: its right
singular vector of the smallest singular value is (n_a; n_b), the axis direction in each
body, and the minimum-norm solution in the other five directions is a point on the axis.
Pose noise enters linearly and averages over the frames.

Units: m, rad. Poses are (R (N, 3, 3), p (N, 3)) in any common frame; NaN frames skipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.fit_error import FitError

DEFAULT_MIN_RANGE = np.deg2rad(10.0)
DEFAULT_MIN_FRAMES = 20
# sigma_6 / sigma_5 of M: ~0 for a clean hinge; near 1 when the relative motion does not
# single out one axis (no rotation, or a spherical joint).
DEFAULT_MAX_SINGULAR_RATIO = 0.1


@dataclass
class JointAxisFit:
    """A joint axis between bodies a and b.

    direction_a, point_a: unit (3,) and (3,) m, the axis in body a's frame; direction_b,
    point_b likewise in body b's frame (the points are the same physical point);
    point_cov_a: (3, 3) m^2; direction_std: rad (first order, from the residual scatter);
    residual_rms: m, RMS of |R_a c_a + p_a - R_b c_b - p_b| over the frames (not an
    accuracy); range: rad, relative rotation swept about the axis; singular_ratio: see
    DEFAULT_MAX_SINGULAR_RATIO; n_frames: frames used.
    """

    direction_a: np.ndarray
    point_a: np.ndarray
    direction_b: np.ndarray
    point_b: np.ndarray
    point_cov_a: np.ndarray
    point_cov_b: np.ndarray
    direction_std: float
    residual_rms: float
    range: float
    singular_ratio: float
    n_frames: int
    condition: dict = field(default_factory=dict)

    def in_frame(self, R: np.ndarray, p: np.ndarray, body: str = "a") -> tuple[np.ndarray, np.ndarray]:
        """The axis (point, direction) mapped by a pose (R, p) of body a (or b)."""
        if body == "a":
            return R @ self.point_a + p, R @ self.direction_a
        return R @ self.point_b + p, R @ self.direction_b

    @property
    def point_std(self) -> float:
        """RMS uncertainty of the axis point perpendicular to the axis, in body a (m)."""
        return float(np.sqrt(max(np.trace(self.point_cov_a), 0.0)))


def fit_joint_axis_sara(R_a: np.ndarray, p_a: np.ndarray, R_b: np.ndarray, p_b: np.ndarray, *,
                        min_range: float = DEFAULT_MIN_RANGE, min_frames: int = DEFAULT_MIN_FRAMES,
                        max_singular_ratio: float = DEFAULT_MAX_SINGULAR_RATIO,
                        reference_direction_a: np.ndarray | None = None) -> JointAxisFit:
    """SARA fit of the hinge between bodies a and b (see the module docstring).

    R_a, R_b: (N, 3, 3); p_a, p_b: (N, 3) m, both bodies' poses in one common frame (NaN
    where a body was not solved). reference_direction_a flips the direction to point along
    it. Raises FitError for too few common frames, too little relative rotation, or motion
    that is not a rotation about one axis.
    """
    R_a, p_a, R_b, p_b = (np.asarray(x, float) for x in (R_a, p_a, R_b, p_b))
    ok = (np.all(np.isfinite(R_a.reshape(len(R_a), -1)), axis=1) & np.all(np.isfinite(p_a), axis=1)
          & np.all(np.isfinite(R_b.reshape(len(R_b), -1)), axis=1) & np.all(np.isfinite(p_b), axis=1))
    N = int(ok.sum())
    cond: dict = {"frames": int(len(ok)), "frames_used": N}
    if N < min_frames:
        raise FitError(f"joint axis fit refused: too few frames in which both bodies are seen: {N} "
                       f"(need at least {min_frames})", cond)
    Ra, pa, Rb, pb = R_a[ok], p_a[ok], R_b[ok], p_b[ok]
    rel = np.einsum("kji,kjl->kil", Ra, Rb)  # R_a^T R_b: b in a
    rv = Rotation.from_matrix(rel @ rel[0].T).as_rotvec()
    # Centre the translations: the fit is invariant to the common frame's origin, and this
    # keeps the normal equations well scaled when the rig sits a metre from the cameras.
    origin = pa.mean(axis=0)
    M = np.concatenate([Ra, -Rb], axis=2).reshape(3 * N, 6)
    y = (pb - pa).reshape(-1)
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    ratio = float(s[-1] / s[-2]) if s[-2] > 0 else np.inf
    v = Vt[-1]
    n_a, n_b = v[:3] / np.linalg.norm(v[:3]), v[3:] / np.linalg.norm(v[3:])
    # minimum-norm solution without the hinge direction
    x = Vt[:5].T @ ((U[:, :5].T @ y) / s[:5])
    c_a, c_b = x[:3], x[3:]
    # choose the point on the axis nearest the bodies' mean position (any point would do;
    # this one is where the link lengths are measured)
    mid_a = np.einsum("kji,kj->ki", Ra, origin - pa).mean(axis=0)
    shift = (mid_a - c_a) @ n_a
    c_a = c_a + shift * n_a
    c_b = c_b + shift * n_b
    angle = rv @ n_a
    rng = float(np.ptp(np.unwrap(angle))) if N > 1 else 0.0
    res = np.einsum("kij,j->ki", Ra, c_a) + pa - np.einsum("kij,j->ki", Rb, c_b) - pb
    rn = np.linalg.norm(res, axis=1)
    dof = max(3 * N - 5, 1)
    s2 = float(np.sum(res ** 2) / dof)
    Vr = Vt[:5]
    cov = s2 * Vr.T @ np.diag(1.0 / s[:5] ** 2) @ Vr
    # direction: the null vector tilts by (noise along it) / (gap to the next singular value)
    dir_std = float(np.sqrt(s2 * 3 * N) / s[-2] / np.sqrt(N)) if s[-2] > 0 else np.inf
    cond.update({"range_deg": float(np.rad2deg(rng)), "singular_ratio": ratio,
                 "singular_values": s.tolist()})
    problems = []
    if rng < min_range:
        problems.append(f"too little range of motion: {np.rad2deg(rng):.2f} deg of relative rotation "
                        f"(need at least {np.rad2deg(min_range):.1f} deg); sweep the joint further")
    if ratio > max_singular_ratio:
        problems.append(f"the relative motion is not a rotation about one axis: singular value ratio "
                        f"{ratio:.3f} (limit {max_singular_ratio})")
    if problems:
        raise FitError("joint axis fit refused: " + "; ".join(problems), cond)
    if reference_direction_a is not None and n_a @ np.asarray(reference_direction_a, float) < 0:
        n_a, n_b = -n_a, -n_b
    return JointAxisFit(direction_a=n_a, point_a=c_a, direction_b=n_b, point_b=c_b,
                        point_cov_a=cov[:3, :3], point_cov_b=cov[3:, 3:], direction_std=dir_std,
                        residual_rms=float(np.sqrt(np.mean(rn ** 2))), range=rng,
                        singular_ratio=ratio, n_frames=N, condition=cond)


def joint_sign(R: np.ndarray, q: np.ndarray, n: np.ndarray) -> float:
    """+1 if rotations R (N, 3, 3) turn about +n as the joint position q (N,) grows, else -1:
    the sign that makes a fitted axis direction the joint's positive axis."""
    ok = np.all(np.isfinite(R.reshape(len(R), -1)), axis=1)
    R, q = R[ok], q[ok]
    ang = np.unwrap(Rotation.from_matrix(R @ R[0].T).as_rotvec() @ n)
    return 1.0 if np.cov(ang, q)[0, 1] >= 0 else -1.0
