"""Mocap frames and joint states of one phase of a procedure, as arrays: `Capture`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Virtual points of a pose-only body: a 60 mm right triangle in the body frame (m).
VIRTUAL_POINTS = np.array([[0.06, 0.0, 0.0], [0.0, 0.06, 0.0], [0.0, 0.0, 0.06]])


@dataclass
class Capture:
    """One phase of a procedure: mocap frames and joint states, as arrays.

    t: (N,) s, frame times; poses: body -> (R (N, 3, 3), p (N, 3)) in the mocap frame, NaN
    where the body was not solved; markers: body -> (N, P, 3) m, NaN where occluded (only
    for bodies whose labelled markers the tracker delivers); joints: arm -> (N, 3) measured
    joints interpolated at the frame times; js: arm -> (t (M,), q (M, 3)) the raw samples.
    """

    name: str
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    markers: dict[str, np.ndarray] = field(default_factory=dict)
    joints: dict[str, np.ndarray] = field(default_factory=dict)
    js: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.t)

    def valid(self, body: str) -> np.ndarray:
        """(N,) frames in which `body` was solved."""
        if body not in self.poses:
            return np.zeros(self.n, bool)
        return np.all(np.isfinite(self.poses[body][1]), axis=1)

    def subset(self, mask: np.ndarray, name: str | None = None) -> "Capture":
        """The frames where `mask` is True (joint-state samples kept whole)."""
        return Capture(name or self.name, self.t[mask],
                       {b: (R[mask], p[mask]) for b, (R, p) in self.poses.items()},
                       {b: X[mask] for b, X in self.markers.items()},
                       {a: q[mask] for a, q in self.joints.items()}, dict(self.js))

    def matrices(self, body: str) -> np.ndarray:
        """(N, 4, 4) poses of `body`, NaN where it was not solved."""
        R, p = self.poses[body]
        T = np.tile(np.eye(4), (self.n, 1, 1))
        T[:, :3, :3], T[:, :3, 3] = R, p
        return T


def concatenate(captures: list[Capture], name: str) -> Capture:
    """Several phases as one Capture (frames in order)."""
    caps = [c for c in captures if c.n]
    if not caps:
        return Capture(name)
    bodies = set.intersection(*(set(c.poses) for c in caps))
    mk = set.intersection(*(set(c.markers) for c in caps))
    arms = set.intersection(*(set(c.joints) for c in caps))
    return Capture(name, np.concatenate([c.t for c in caps]),
                   {b: (np.concatenate([c.poses[b][0] for c in caps]),
                        np.concatenate([c.poses[b][1] for c in caps])) for b in bodies},
                   {b: np.concatenate([c.markers[b] for c in caps]) for b in mk},
                   {a: np.concatenate([c.joints[a] for c in caps]) for a in arms}, {})


def body_points(cap: Capture, body: str) -> tuple[np.ndarray, str]:
    """Points (N, P, 3) m of `body` in the mocap frame and where they come from.

    The labelled markers when the tracker delivers them ("markers"), otherwise three
    virtual points rigidly attached to the solved pose ("pose"): they move exactly as
    markers on the body would, so the axis fits of appendix A.1 apply to either.
    """
    if body in cap.markers:
        return cap.markers[body], "markers"
    R, p = cap.poses[body]
    return np.einsum("kij,vj->kvi", R, VIRTUAL_POINTS) + p[:, None, :], "pose"
