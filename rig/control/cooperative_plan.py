"""The cooperative plan: where every tool tip should be (eq. 6.2-6.3), and the user's increments.

The master's motion (a translation and an object rotation about the tips' centroid, on a
minimum-jerk profile) is planned for every arm from where the tips were at the start.
User increments (keyboard, ROS) are targets the applied offsets slew toward, so that an
increment is a short ramp, not a step in one cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def min_jerk(s: float) -> tuple[float, float, float]:
    """Minimum-jerk profile on [0, 1]: (position, d/ds, d2/ds2)."""
    s = min(max(s, 0.0), 1.0)
    p = 10 * s**3 - 15 * s**4 + 6 * s**5
    v = 30 * s**2 - 60 * s**3 + 30 * s**4
    a = 60 * s - 180 * s**2 + 120 * s**3
    return p, v, a


def euler_xyz(angles: np.ndarray) -> np.ndarray:
    """Rotation for x, y, z Euler angle increments (rad): R = Rz Ry Rx."""
    a, b, c = angles
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass
class Motion:
    """Master motion in the world frame: translation (m) and object rotation (rad) over
    `duration` s, starting `start` s after the controller starts."""

    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    duration: float = 5.0
    start: float = 2.0


class UserOffsets:
    """The user's increments: targets (`force_offset` N, `translation` m in the world,
    `rotation` rad, Euler x-y-z of the object) and the applied offsets that slew toward
    them at `rates` (N/s, m/s, rad/s)."""

    def __init__(self, slew_translation: float, slew_rotation: float, slew_force: float):
        self.slew_translation = slew_translation
        self.slew_rotation = slew_rotation
        self.slew_force = slew_force
        self.force_offset = 0.0
        self.translation = np.zeros(3)
        self.rotation = np.zeros(3)
        self.applied_force = 0.0
        self.applied_translation = np.zeros(3)
        self.applied_rotation = np.zeros(3)
        self.velocity = np.zeros(3)   # m/s of the applied translation over the last slew

    def slew(self, dt: float) -> None:
        """Move the applied offsets toward their targets over `dt` s."""
        if (self.applied_force == self.force_offset
                and (self.applied_translation == self.translation).all()
                and (self.applied_rotation == self.rotation).all()):
            # nothing left to slew (the usual case): the same result as below, without its cost
            self.velocity = np.zeros(3)
            return

        def toward(applied, target, rate):
            d = np.asarray(target, float) - applied
            n = float(np.linalg.norm(d))
            limit = rate * dt
            return target if n <= limit else applied + d * (limit / n)

        before = self.applied_translation.copy()
        self.applied_translation = np.array(toward(self.applied_translation, self.translation,
                                                   self.slew_translation), float)
        self.velocity = (self.applied_translation - before) / dt
        self.applied_rotation = np.array(toward(self.applied_rotation, self.rotation, self.slew_rotation), float)
        self.applied_force = float(toward(np.array([self.applied_force]),
                                          np.array([self.force_offset]), self.slew_force)[0])


class Plan:
    """World-frame desired tips of every arm from their start `x0` (eq. 6.2-6.3)."""

    def __init__(self, motion: Motion, arms: list[str]):
        self.motion = motion
        self.arms = list(arms)
        self.t0: float | None = None
        self.x0: dict[str, np.ndarray] = {}
        self.centroid0 = np.zeros(3)

    def start(self, t0: float, x0: dict[str, np.ndarray]) -> None:
        self.t0 = t0
        self.x0 = x0
        self.centroid0 = np.mean([x0[a] for a in self.arms], axis=0)

    def desired(self, t: float, offsets: UserOffsets, targets: bool = False
                ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Desired tip positions, velocities and accelerations, with the user offsets
        applied so far, or with their targets (`targets=True`: what a limit check of the
        rest of the plan needs)."""
        m = self.motion
        s = (t - self.t0 - m.start) / m.duration if m.duration > 0 else 1.0
        p, v, a = min_jerk(s)
        inside = 0.0 <= s <= 1.0
        v, a = (v / m.duration, a / m.duration**2) if inside else (0.0, 0.0)
        shift = p * m.translation + (offsets.translation if targets else offsets.applied_translation)
        angles = p * m.rotation + (offsets.rotation if targets else offsets.applied_rotation)
        if angles.any():
            R = euler_xyz(angles)
            # rate of the object's rotation along the planned profile: a finite difference
            eps = 1e-4
            dR = (euler_xyz(angles + eps * m.rotation) - R) / eps * v if m.rotation.any() else np.zeros((3, 3))
        else:
            R, dR = np.eye(3), np.zeros((3, 3))
        xd, vd, ad = {}, {}, {}
        rotated = angles.any()
        for arm in self.arms:
            r0 = self.x0[arm] - self.centroid0
            # without a rotation R r0 = r0 and dR r0 = 0 exactly: the products are skipped
            xd[arm] = self.centroid0 + shift + (R @ r0 if rotated else r0)
            vd[arm] = v * m.translation + (dR @ r0 if rotated else 0.0) + (0.0 if targets else offsets.velocity)
            ad[arm] = a * m.translation
        return xd, vd, ad
