"""Quaternion component order, made explicit.

Motive CSV exports and ROS geometry_msgs/Quaternion store (x, y, z, w) (scalar last);
many other tools (Eigen's constructor, Vicon, some mocap bridges, Pinocchio's
`Quaternion(w, x, y, z)`) use (w, x, y, z) (scalar first). Mixing the two silently
gives a rotation that is wrong by a large angle but still a valid unit quaternion, so
every place that touches a quaternion array says which order it holds and converts with
the named functions here, never by ad-hoc slicing.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

XYZW = "xyzw"
WXYZ = "wxyz"
ORDERS = (XYZW, WXYZ)


def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    """Reorder quaternions (..., 4) from (x, y, z, w) to (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 3:4], q[..., 0:3]], axis=-1)


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """Reorder quaternions (..., 4) from (w, x, y, z) to (x, y, z, w)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def reorder_quaternion(q: np.ndarray, src: str, dst: str) -> np.ndarray:
    """Convert quaternions (..., 4) from component order `src` to `dst` ("xyzw"/"wxyz")."""
    for o in (src, dst):
        if o not in ORDERS:
            raise ValueError(f"unknown quaternion order {o!r}; use one of {ORDERS}")
    if src == dst:
        return np.array(q, dtype=float)
    return xyzw_to_wxyz(q) if src == XYZW else wxyz_to_xyzw(q)


def quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (x, y, z, w) order.

    Quaternions need not be unit (they are normalised, as scipy's Rotation does); a zero
    quaternion raises ValueError. NaN quaternions (occluded samples) give NaN matrices
    rather than an error, so a whole track converts in one call and the occlusion mask
    stays the source of truth. One quaternion is converted in plain floats (3 us against
    scipy's 45 us): the ROS mocap driver converts one per body message, 1 320 a second
    for 11 bodies at 120 Hz, on the thread that must keep up with them.
    """
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):
        return _one_quat_to_matrix(*q.tolist())
    flat = q.reshape(-1, 4)
    out = np.full((flat.shape[0], 3, 3), np.nan)
    ok = np.all(np.isfinite(flat), axis=1)
    if np.any(ok):
        # scipy's from_quat is scalar-last, i.e. exactly (x, y, z, w).
        out[ok] = Rotation.from_quat(flat[ok]).as_matrix()
    return out.reshape(q.shape[:-1] + (3, 3))


def _one_quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = x * x + y * y + z * z + w * w
    if not math.isfinite(n):
        return np.full((3, 3), np.nan)
    if n == 0.0:
        raise ValueError("a zero quaternion is not a rotation")
    s = 2.0 / n
    xx, yy, zz = x * x * s, y * y * s, z * z * s
    xy, xz, yz = x * y * s, x * z * s, y * z * s
    wx, wy, wz = w * x * s, w * y * s, w * z * s
    return np.array([[1.0 - yy - zz, xy - wz, xz + wy],
                     [xy + wz, 1.0 - xx - zz, yz - wx],
                     [xz - wy, yz + wx, 1.0 - xx - yy]])


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) in (x, y, z, w) order, w >= 0, from rotations (..., 3, 3).

    One matrix goes through Pinocchio's (Eigen's) conversion, 3 us against scipy's 190 us:
    the cooperative loop converts two per slave per tick. A stack of them is converted in
    plain floats when small (a mocap frame's 11 bodies: 64 us against scipy's 170 us), by
    scipy when large.
    Matrices are taken as rotations (orthonormal, det +1); NaN ones give NaN quaternions.
    """
    R = np.asarray(R, dtype=float)
    if R.shape == (3, 3):
        if not np.isfinite(R).all():
            return np.full(4, np.nan)
        q = _pinocchio().Quaternion(R).coeffs()  # Eigen's coefficients: (x, y, z, w)
        q = q / np.sqrt(q @ q)
        return -q if q[3] < 0 else q
    flat = R.reshape(-1, 3, 3)
    out = np.full((flat.shape[0], 4), np.nan)
    ok = np.all(np.isfinite(flat), axis=(1, 2))
    if np.any(ok):
        q = _matrices_to_quats(flat[ok])
        q[q[:, 3] < 0] *= -1.0  # one canonical sign so written files are reproducible
        out[ok] = q
    return out.reshape(R.shape[:-2] + (4,))


def _matrices_to_quats(R: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (x, y, z, w) of finite rotations (N, 3, 3): scipy's for
    many, plain floats for a few (numpy's per-call cost dominates there)."""
    if len(R) > SMALL_BATCH:
        return Rotation.from_matrix(R).as_quat()  # scalar-last
    return np.array([_one_matrix_to_quat(*m) for m in R.reshape(-1, 9).tolist()]).reshape(-1, 4)


#: stacks of at most this many rotations are converted one by one in plain floats
SMALL_BATCH = 64


def _one_matrix_to_quat(m00, m01, m02, m10, m11, m12, m20, m21, m22) -> tuple:
    # the largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 keeps the division well conditioned
    tw, tx = 1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22
    ty, tz = 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22
    big = max(tw, tx, ty, tz)
    if big == tw:
        q = (m21 - m12, m02 - m20, m10 - m01, tw)
    elif big == tx:
        q = (tx, m01 + m10, m02 + m20, m21 - m12)
    elif big == ty:
        q = (m01 + m10, ty, m12 + m21, m02 - m20)
    else:
        q = (m02 + m20, m12 + m21, tz, m10 - m01)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _pinocchio():
    import pinocchio

    return pinocchio
