"""Synthetic marker data with known truth, for the fits' tests and benchmarks.

Not a simulator of the rig (that is the `rig` kernel's simulated world): these are the
minimal geometric scenes the fitting mathematics is checked against, with seeded
Gaussian marker noise. Units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.registration import rigid_body_poses


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix."""
    return Rotation.random(random_state=rng.integers(2**31)).as_matrix()


def axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) by angles (N,) rad about a unit axis (3,)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return Rotation.from_rotvec(np.outer(np.atleast_1d(angle), axis)).as_matrix()


def marker_template(rng: np.random.Generator, n: int = 3, radius: float = 0.04) -> np.ndarray:
    """n markers (n, 3) m of a rigid body, spread on a circle of `radius` with
    irregular spacing (as real marker bodies are, so they are not symmetric), centred."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n)) if n > 3 else np.array([0.0, 2.1, 4.0]) + rng.uniform(0, 0.3, 3)
    pts = np.stack([radius * np.cos(ang), radius * np.sin(ang), rng.uniform(-0.005, 0.005, n)], axis=1)
    return pts - pts.mean(axis=0)


@dataclass
class HingeScene:
    """A body rotating about a known axis relative to a reference body.

    ref_markers: (N, 3, 3) and moving_markers: (N, P, 3) noisy marker positions in the
    mocap frame; ref_template: (3, 3) reference markers in the reference body frame;
    direction, point: the true axis in the reference body frame; angles: (N,) rad.
    """

    ref_markers: np.ndarray
    moving_markers: np.ndarray
    ref_template: np.ndarray
    direction: np.ndarray
    point: np.ndarray
    angles: np.ndarray
    R_ref: np.ndarray
    p_ref: np.ndarray

    def markers_in_reference(self, exact_reference: bool = False) -> np.ndarray:
        """The moving markers expressed in the reference body frame, tracked per frame
        from its noisy markers, or (exact_reference) with its true pose, as for a static
        reference whose pose is averaged over many frames."""
        from calibration.registration import to_frame
        if exact_reference:
            n = len(self.moving_markers)
            return to_frame(self.moving_markers, np.broadcast_to(self.R_ref, (n, 3, 3)),
                            np.broadcast_to(self.p_ref, (n, 3)))
        R, p, _ = rigid_body_poses(self.ref_markers, self.ref_template)
        return to_frame(self.moving_markers, R, p)


def hinge_scene(rng: np.random.Generator, *, angle_range: tuple[float, float] = (-1.5, 1.5),
                n_frames: int = 300, n_markers: int = 3, noise: float = 0.25e-3,
                marker_radius: tuple[float, float] = (0.05, 0.12),
                axial_spread: float = 0.06, azimuth_spread: float = 1.0,
                ref_distance: float = 0.15, direction: np.ndarray | None = None,
                point: np.ndarray | None = None) -> HingeScene:
    """Markers of a body swept over `angle_range` (rad, linearly over n_frames) about a
    random axis, and a static reference body ~ref_distance m away; isotropic Gaussian
    marker noise `noise` (m) on every marker in every frame. The moving markers sit on
    one side of the axis within `azimuth_spread` rad, like a marker body on a link.
    direction, point: the axis in the reference body frame (random when None)."""
    R_ref = random_rotation(rng)
    p_ref = rng.uniform(-0.5, 0.5, 3)
    ref_template = marker_template(rng, 3, 0.04)
    rand_dir = rng.normal(size=3)
    rand_point = rng.normal(size=3) * ref_distance / np.sqrt(3)  # in the reference body frame
    direction = rand_dir if direction is None else np.asarray(direction, float)
    direction = direction / np.linalg.norm(direction)
    if point is None:
        point = rand_point - (rand_point @ direction) * direction
    point = np.asarray(point, float)
    # moving markers at radii and axial positions around the axis
    e1 = np.cross(direction, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.1:
        e1 = np.cross(direction, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(direction, e1)
    r = rng.uniform(*marker_radius, n_markers)
    phi = np.linspace(-azimuth_spread / 2, azimuth_spread / 2, n_markers) + rng.uniform(-0.1, 0.1, n_markers)
    h = rng.uniform(-axial_spread / 2, axial_spread / 2, n_markers)
    m0 = point + np.outer(r * np.cos(phi), e1) + np.outer(r * np.sin(phi), e2) + np.outer(h, direction)
    angles = np.linspace(angle_range[0], angle_range[1], n_frames)
    Rk = axis_rotation(direction, angles)
    moving_ref = np.einsum("kij,pj->kpi", Rk, m0 - point) + point  # in the reference frame
    moving = moving_ref @ R_ref.T + p_ref
    ref = np.broadcast_to(ref_template @ R_ref.T + p_ref, (n_frames, 3, 3))
    moving = moving + rng.normal(scale=noise, size=moving.shape)
    ref = ref + rng.normal(scale=noise, size=ref.shape)
    return HingeScene(ref_markers=ref, moving_markers=moving, ref_template=ref_template,
                      direction=direction, point=point, angles=angles,
                      R_ref=R_ref, p_ref=p_ref)


@dataclass
class PivotScene:
    """A tool body pivoting about a known RCM.

    R, p: (N, 3, 3), (N, 3) body poses estimated from the noisy markers (as the mocap
    system does); rcm: true pivot (mocap frame, m); tip: true body origin -> RCM vector
    in the body frame (m); markers: (N, P, 3) the noisy markers.
    """

    R: np.ndarray
    p: np.ndarray
    rcm: np.ndarray
    tip: np.ndarray
    markers: np.ndarray
    template: np.ndarray


def psm_sweep_angles(n_frames: int, q1_range: float = 1.5, q2_range: float = 0.9
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Thesis 4.1.1 sweeps: q1 over +/-q1_range with q2 = 0, then q2 over +/-q2_range
    with q1 = 0, n_frames in total (rad)."""
    n1 = n_frames // 2
    q1 = np.r_[np.linspace(-q1_range, q1_range, n1), np.zeros(n_frames - n1)]
    q2 = np.r_[np.zeros(n1), np.linspace(-q2_range, q2_range, n_frames - n1)]
    return q1, q2


def pivot_scene(rng: np.random.Generator, *, n_frames: int = 400, q1_range: float = 1.5,
                q2_range: float = 0.9, noise: float = 0.25e-3, tip_length: float = 0.15,
                marker_radius: float = 0.05, q1: np.ndarray | None = None,
                q2: np.ndarray | None = None) -> PivotScene:
    """A PSM-like pivot: the tool body rotates about the RCM by q1 (about the base's
    first axis) then q2 (perpendicular), both axes through the RCM; the body origin sits
    `tip_length` m from the RCM. Marker noise `noise` m; poses estimated per frame."""
    if q1 is None or q2 is None:
        q1, q2 = psm_sweep_angles(n_frames, q1_range, q2_range)
    R0 = random_rotation(rng)
    rcm = rng.uniform(-0.5, 0.5, 3)
    tip = rng.normal(size=3)
    tip *= tip_length / np.linalg.norm(tip)
    Rk = R0 @ axis_rotation([0, 0, 1], q1) @ axis_rotation([1, 0, 0], q2)
    p = rcm - np.einsum("kij,j->ki", Rk, tip)
    template = marker_template(rng, 3, marker_radius)
    markers = np.einsum("kij,pj->kpi", Rk, template) + p[:, None, :]
    markers = markers + rng.normal(scale=noise, size=markers.shape)
    R_est, p_est, _ = rigid_body_poses(markers, template)
    return PivotScene(R=R_est, p=p_est, rcm=rcm, tip=tip, markers=markers, template=template)


@dataclass
class RegistrationScene:
    """Two arms' bases with a known transform T_1_2 (PSM2 base -> PSM1 base).

    tips_1, tips_2: (M, 3) noisy tool-tip positions touching M common points, each in
    its own base frame; T_m_b1, T_m_b2: (N, 4, 4) base body poses in the mocap frame
    estimated from noisy markers over N static frames.
    """

    T_1_2: np.ndarray
    tips_1: np.ndarray
    tips_2: np.ndarray
    T_m_b1: np.ndarray
    T_m_b2: np.ndarray


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def registration_scene(rng: np.random.Generator, *, n_points: int = 30, tip_noise: float = 0.25e-3,
                       workspace: float = 0.08, n_frames: int = 200, noise: float = 0.25e-3,
                       marker_radius: float = 0.05) -> RegistrationScene:
    """Two bases ~0.3 m apart facing each other roughly; touch points uniform in a cube
    of half-side `workspace` m between them with `tip_noise` m on each arm's tip
    (kinematics plus touching error); mocap base bodies with `noise` m marker noise."""
    Rz = axis_rotation([0, 0, 1], [np.pi + rng.uniform(-0.5, 0.5)])[0]
    T_m_b1 = _T(random_rotation(rng), rng.uniform(-0.5, 0.5, 3))
    T_1_2 = _T(Rz @ axis_rotation(rng.normal(size=3), [rng.uniform(0, 0.2)])[0],
               np.array([0.3, 0.0, 0.0]) + rng.uniform(-0.05, 0.05, 3))
    T_m_b2 = T_m_b1 @ T_1_2
    centre = np.array([0.15, 0.0, -0.1])
    pts_1 = centre + rng.uniform(-workspace, workspace, (n_points, 3))
    T_2_1 = np.linalg.inv(T_1_2)
    pts_2 = pts_1 @ T_2_1[:3, :3].T + T_2_1[:3, 3]
    tips_1 = pts_1 + rng.normal(scale=tip_noise, size=pts_1.shape)
    tips_2 = pts_2 + rng.normal(scale=tip_noise, size=pts_2.shape)
    poses = []
    for T in (T_m_b1, T_m_b2):
        tpl = marker_template(rng, 3, marker_radius)
        mk = np.broadcast_to(tpl @ T[:3, :3].T + T[:3, 3], (n_frames, 3, 3))
        mk = mk + rng.normal(scale=noise, size=mk.shape)
        R, p, _ = rigid_body_poses(mk, tpl)
        Ts = np.tile(np.eye(4), (n_frames, 1, 1))
        Ts[:, :3, :3], Ts[:, :3, 3] = R, p
        poses.append(Ts)
    return RegistrationScene(T_1_2=T_1_2, tips_1=tips_1, tips_2=tips_2,
                             T_m_b1=poses[0], T_m_b2=poses[1])
