"""Quaternion component order, made explicit.

Motive CSV exports and ROS geometry_msgs/Quaternion store (x, y, z, w) (scalar last);
many other tools (Eigen's constructor, Vicon, some mocap bridges, Pinocchio's
`Quaternion(w, x, y, z)`) use (w, x, y, z) (scalar first). Mixing the two silently
gives a rotation that is wrong by a large angle but still a valid unit quaternion, so
every place that touches a quaternion array says which order it holds and converts with
the named functions here, never by ad-hoc slicing.
"""

from __future__ import annotations

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
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4) in (x, y, z, w) order.

    NaN quaternions (occluded samples) give NaN matrices rather than an error, so a
    whole track converts in one call and the occlusion mask stays the source of truth.
    """
    q = np.asarray(q, dtype=float)
    flat = q.reshape(-1, 4)
    out = np.full((flat.shape[0], 3, 3), np.nan)
    ok = np.all(np.isfinite(flat), axis=1)
    if np.any(ok):
        # scipy's from_quat is scalar-last, i.e. exactly (x, y, z, w).
        out[ok] = Rotation.from_quat(flat[ok]).as_matrix()
    return out.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) in (x, y, z, w) order, w >= 0, from rotations (..., 3, 3).

    One matrix goes through Pinocchio's (Eigen's) conversion, 3 us against scipy's 190 us:
    the cooperative loop converts two per slave per tick."""
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
        q = Rotation.from_matrix(flat[ok]).as_quat()  # scalar-last
        q[q[:, 3] < 0] *= -1.0  # one canonical sign so written files are reproducible
        out[ok] = q
    return out.reshape(R.shape[:-2] + (4,))


def _pinocchio():
    import pinocchio

    return pinocchio
