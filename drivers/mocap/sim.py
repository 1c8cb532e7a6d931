"""The motion-capture fake: marker bodies of the simulated rig seen by an optical tracker.

`SimTracker` implements `drivers.interfaces.Tracker` on the simulated world's clock:

* capture: at `rate` Hz (the first clock tick at or after each capture instant) it reads
  the true marker positions of every marker body (`world.marker_positions()`, three per
  body, metres, world frame) and adds Gaussian noise of `noise` m per coordinate;
* solve: each body's pose is re-estimated from its noisy markers by a least-squares
  rigid fit (Kabsch) against the body's marker layout, as Motive solves a rigid body, so
  the pose noise has the structure of the real thing (rotation noise grows as the
  markers get closer together) instead of being added to the pose directly. The RMS
  residual is kept as Motive's "mean marker error";
* occlusion: with probability `occlusion` a body is occluded in a frame: a random non-empty
  subset of its markers is hidden and, with three markers per body, the body cannot be
  solved. Hidden markers and unsolved bodies are `None` in the frame (never zeros) and
  counted in `stats`;
* latency: a frame captured at t is delivered by `frames()`/`latest()` only once the
  clock reached t + `latency`; its time stamp stays the capture time, as Motive stamps;
* quaternion order: the source reports each body's orientation as a quaternion whose
  component order is `quaternion_order` ("xyzw" like Motive and ROS, or "wxyz" like
  Vicon or Eigen). `SimFrame.quaternions` hold exactly that order; the `Pose.rotation`
  matrices of `SimFrame.bodies` are decoded from those quaternions with the declared
  order through `matrix_from_quaternion`, so a wrong declaration shows as a wrong pose;
* the cable: `unplug()` stops the stream (a fault a test or the simulated operator
  injects); once no frame was delivered for `stale_timeout` s of the clock, `frames()` and
  `latest()` raise `MocapStaleError` as the drivers do (the frames delivered before stay
  buffered), and `latest()` raises it before the first frame too.

Frames are in the world frame of the simulated rig (the mocap frame). Units: m, s.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.interfaces import Pose, TrackerFrame
from drivers.mocap.ros_tracker import MocapStaleError
from drivers.common.quaternion import ORDERS, XYZW, matrix_to_quat_xyzw, quat_xyzw_to_matrix, reorder_quaternion


def quaternion_from_matrix(R: np.ndarray, order: str) -> np.ndarray:
    """Unit quaternion(s) (..., 4) of rotation(s) R (..., 3, 3) in component `order`."""
    return reorder_quaternion(matrix_to_quat_xyzw(R), XYZW, order)


def matrix_from_quaternion(q: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrix/matrices (..., 3, 3) from quaternion(s) (..., 4) stored in `order`."""
    return quat_xyzw_to_matrix(reorder_quaternion(q, order, XYZW))


def kabsch(reference: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigid fit measured ~ R @ reference + p, for one body or a stack of bodies.

    reference, measured: (..., n, 3) marker positions (m), n >= 3 non-collinear.
    Returns (R (..., 3, 3), p (..., 3), rms residual (...,) in m). The determinant
    correction keeps R a rotation (never a reflection) however noisy the markers are.
    The stacked form is one batched SVD, so a whole frame of bodies costs about one fit.
    """
    ref = np.asarray(reference, float)
    mea = np.asarray(measured, float)
    cr, cm = ref.mean(axis=-2, keepdims=True), mea.mean(axis=-2, keepdims=True)
    H = np.swapaxes(ref - cr, -1, -2) @ (mea - cm)
    U, _, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, -1, -2), np.swapaxes(U, -1, -2)
    d = np.where(np.linalg.det(V @ Ut) < 0, -1.0, 1.0)
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[..., 2, 2] = d
    R = V @ D @ Ut
    p = cm[..., 0, :] - (R @ cr[..., 0, :, None])[..., 0]
    fitted = ref @ np.swapaxes(R, -1, -2) + p[..., None, :]
    rms = np.sqrt(np.mean(np.sum((fitted - mea) ** 2, axis=-1), axis=-1))
    return R, p, rms


def marker_name(body: str, k: int) -> str:
    """Motive's label of marker k (0-based) of a rigid body: "<body>:Marker<k+1>"."""
    return f"{body}:Marker{k + 1}"


@dataclass(frozen=True)
class SimFrame(TrackerFrame):
    """A TrackerFrame plus what the source itself reports.

    quaternions: body -> (4,) in `quaternion_order` (None when occluded);
    marker_error: body -> RMS marker residual of the rigid fit (m; None when occluded).
    """

    quaternions: dict[str, np.ndarray | None] = field(default_factory=dict)
    quaternion_order: str = XYZW
    marker_error: dict[str, float | None] = field(default_factory=dict)


@dataclass
class SimTrackerStats:
    """captured: frames taken; delivered: frames handed out by frames()/latest();
    occluded: per body, frames in which it was occluded; hidden_markers: markers hidden."""

    captured: int = 0
    delivered: int = 0
    occluded: dict[str, int] = field(default_factory=dict)
    hidden_markers: int = 0


class SimTracker:
    """Tracker fake over `world` on `clock` (see the module docstring).

    noise: marker noise, m per coordinate (1 sigma); latency: s from capture to delivery;
    occlusion: probability per body and frame; rate: Hz; quaternion_order: the source's
    component order ("xyzw" or "wxyz"); seed: its own random stream (independent of the
    world's); bodies: names of the marker bodies to track (default all); stale_timeout: s
    without a frame before reads raise (`[mocap] stale_timeout`).
    """

    def __init__(self, world, clock, noise: float = 0.00025, latency: float = 0.005,
                 occlusion: float = 0.0, rate: float = 120.0, quaternion_order: str = XYZW,
                 seed: int = 0, bodies: list[str] | None = None, max_buffer: int = 100_000,
                 stale_timeout: float = 2.0):
        if quaternion_order not in ORDERS:
            raise ValueError(f"quaternion_order must be one of {ORDERS}, got {quaternion_order!r}")
        if noise < 0 or latency < 0 or not 0 <= occlusion < 1 or rate <= 0:
            raise ValueError("SimTracker needs noise >= 0 m, latency >= 0 s, 0 <= occlusion < 1, rate > 0 Hz")
        layouts = {mb.name: np.asarray(mb.offsets, float) for mb in world.marker_bodies}
        names = list(layouts) if bodies is None else list(bodies)
        for b in names:
            if b not in layouts:
                raise ValueError(f"no marker body {b!r} in the simulated rig; it has {list(layouts)}")
        self.world = world
        self.clock = clock
        self.noise = float(noise)
        self.latency = float(latency)
        self.occlusion = float(occlusion)
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        self.quaternion_order = quaternion_order
        self.bodies = tuple(names)
        self.layouts = {b: layouts[b] for b in self.bodies}
        self._layout_stack = np.stack([self.layouts[b] for b in self.bodies])
        self.rng = np.random.default_rng(seed)
        self.stats = SimTrackerStats(occluded={b: 0 for b in self.bodies})
        self._next_capture = clock.now()
        self._in_flight: deque[SimFrame] = deque()  # captured, not yet delivered (latency)
        self._delivered: deque[SimFrame] = deque(maxlen=max_buffer)
        self._latest: SimFrame | None = None
        self._closed = False
        if not stale_timeout > 0:
            raise ValueError(f"stale_timeout must be > 0 s, got {stale_timeout}")
        self.stale_timeout = float(stale_timeout)
        self.unplugged = False
        self._last_delivery = clock.now() + self.latency  # the first frame is due then
        clock.add_listener(self._on_tick)

    # -- device side (clock listener) -------------------------------------------------
    def _on_tick(self, t: float) -> None:
        if self.unplugged:
            return
        eps = 1e-9
        if t + eps >= self._next_capture:
            self._in_flight.append(self.capture(t))
            # next instant on the fixed grid; a stalled clock does not cause a burst
            self._next_capture += self.period * max(1, int((t + eps - self._next_capture) // self.period) + 1)
        while self._in_flight and self._in_flight[0].t + self.latency <= t + eps:
            frame = self._in_flight.popleft()
            self._delivered.append(frame)
            self._latest = frame
            self._last_delivery = t

    def capture(self, t: float) -> SimFrame:
        """One frame of the present world state stamped `t` (s); not queued for delivery."""
        truth = self.world.marker_positions()
        measured = np.stack([truth[b] for b in self.bodies])
        measured = measured + self.rng.normal(0.0, self.noise, measured.shape)
        hidden = np.zeros(measured.shape[:2], bool)
        if self.occlusion > 0:
            for i in np.flatnonzero(self.rng.random(len(self.bodies)) < self.occlusion):
                k = int(self.rng.integers(1, measured.shape[1] + 1))
                hidden[i, self.rng.choice(measured.shape[1], size=k, replace=False)] = True
        R, p, rms = kabsch(self._layout_stack, measured)
        q = quaternion_from_matrix(R, self.quaternion_order)
        # The consumer's side: decode the source quaternions in their declared order.
        R_decoded = matrix_from_quaternion(q, self.quaternion_order)
        bodies: dict[str, Pose | None] = {}
        markers: dict[str, np.ndarray | None] = {}
        quats: dict[str, np.ndarray | None] = {}
        errors: dict[str, float | None] = {}
        for i, b in enumerate(self.bodies):
            for k in range(measured.shape[1]):
                markers[marker_name(b, k)] = None if hidden[i, k] else measured[i, k]
            if hidden[i].any():
                self.stats.occluded[b] += 1
                self.stats.hidden_markers += int(hidden[i].sum())
                bodies[b] = quats[b] = errors[b] = None
                continue
            quats[b] = q[i]
            errors[b] = float(rms[i])
            bodies[b] = Pose(t, p[i], R_decoded[i], "world")
        self.stats.captured += 1
        return SimFrame(t=t, bodies=bodies, markers=markers, quaternions=quats,
                        quaternion_order=self.quaternion_order, marker_error=errors)

    # -- Tracker interface ------------------------------------------------------------
    def unplug(self) -> None:
        """Pull the tracker's cable: no frame is captured or delivered from now on."""
        self.unplugged = True
        self._in_flight.clear()

    def check_stale(self) -> None:
        """Raise MocapStaleError once no frame was delivered for `stale_timeout` s."""
        age = self.clock.now() - self._last_delivery
        if age > self.stale_timeout:
            why = "its cable is unplugged" if self.unplugged else "the clock ran on without a capture"
            raise MocapStaleError(f"simulated mocap stale beyond {self.stale_timeout:g} s ([mocap] stale_timeout): "
                                  f"no frame for {age:.3f} s ({why})")

    def frames(self) -> list[SimFrame]:
        """Every frame delivered since the last call, oldest first; raises MocapStaleError
        (keeping them) when the stream is stale."""
        self.check_stale()
        out = list(self._delivered)
        self._delivered.clear()
        self.stats.delivered += len(out)
        return out

    def latest(self) -> SimFrame:
        """The newest delivered frame; raises MocapStaleError before the first one arrives
        or when the stream is stale."""
        self.check_stale()
        if self._latest is None:
            raise MocapStaleError(f"no mocap frame delivered yet (rate {self.rate:g} Hz, latency "
                                  f"{self.latency * 1e3:.1f} ms); tick the clock first")
        return self._latest

    def close(self) -> None:
        """Stop capturing (removes the clock listener)."""
        if not self._closed:
            self._closed = True
            remove = getattr(self.clock, "remove_listener", None)
            if remove is not None:
                remove(self._on_tick)


def record_to_motive_csv(path: str | Path, frames: list[TrackerFrame], *, quat_order: str = XYZW,
                         units: str = "Millimeters", frame_rate: float | None = None) -> Path:
    """Write tracker frames as an OptiTrack Motive CSV export (`drivers.mocap.motive_csv` layout).

    Rigid bodies and labelled markers of the first frame are the columns; occluded samples
    become empty cells. quat_order: the order of the file's rotation columns (Motive writes
    "xyzw"). units: "Millimeters" (Motive's default) or "Meters". The mean marker error
    comes from `SimFrame.marker_error` when the frames carry it (else empty).
    """
    from drivers.mocap.motive_csv import write_motive_csv

    if not frames:
        raise ValueError("record_to_motive_csv: no frames to write")
    n = len(frames)
    time = np.array([f.t for f in frames], float)
    body_names = list(frames[0].bodies)
    marker_names = list(frames[0].markers)
    rigid = {}
    for b in body_names:
        pos = np.full((n, 3), np.nan)
        quat = np.full((n, 4), np.nan)
        err = np.full(n, np.nan)
        for k, f in enumerate(frames):
            pose = f.bodies.get(b)
            if pose is None:
                continue
            pos[k] = pose.position
            quat[k] = matrix_to_quat_xyzw(pose.rotation)
            e = getattr(f, "marker_error", {}).get(b)
            if e is not None:
                err[k] = e
        rigid[b] = (pos, quat, err)
    markers = {}
    for m in marker_names:
        pos = np.full((n, 3), np.nan)
        for k, f in enumerate(frames):
            v = f.markers.get(m)
            if v is not None:
                pos[k] = v
        markers[m] = pos
    return write_motive_csv(path, time, rigid_bodies=rigid, markers=markers, units=units,
                            quat_order=quat_order, frame_rate=frame_rate)
