"""The device interfaces that procedures use (docs/fakes.md).

A procedure only ever sees these. A driver takes its transport (a ROS 2 node, a pyserial
port, a python-can bus) and implements one of them; its fake sits next to it and behaves
like the device. Times are seconds on the rig clock (`Clock.now()`), units are SI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class JointState:
    """One arm sample: positions (rad, m for joint 3), velocities, efforts (N m, N)."""

    t: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    name: tuple[str, ...] = ()


@dataclass(frozen=True)
class Pose:
    """A rigid transform: position (m) and rotation matrix (3x3) in a named frame."""

    t: float
    position: np.ndarray
    rotation: np.ndarray
    frame: str = ""

    def matrix(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.position
        return T


@dataclass(frozen=True)
class ForceSample:
    """One load-cell sample: tension (N, positive when the object is stretched)."""

    t: float
    force: float
    raw: int = 0
    seq: int = 0


@dataclass(frozen=True)
class TrackerFrame:
    """One mocap frame: rigid bodies by name (None when occluded) and labelled markers (m)."""

    t: float
    bodies: dict[str, Pose | None] = field(default_factory=dict)
    markers: dict[str, np.ndarray | None] = field(default_factory=dict)


@runtime_checkable
class Arm(Protocol):
    """A dVRK arm in the CRTK vocabulary (joints 1-3 of a PSM for this rig)."""

    name: str

    def measured_js(self) -> JointState:
        """The newest measured joint state of joints 1-3, stamped on the rig clock (s)."""
        ...

    def drain_js(self) -> list[JointState]:
        """Every measured joint state since the last drain, oldest first: a loop that could
        not look at every sample (held up, over the wire) still records them all."""
        ...

    def setpoint_js(self) -> JointState:
        """The arm's joint set-point: after `servo_jp`, its position is the one commanded."""
        ...

    def measured_cp(self) -> Pose:
        """The tool tip from the measured joints, as the dVRK's measured_cp: its PSM's tool tip
        (the tool's wrist straight on this rig's 3-joint arm) in the arm's base frame, which
        is the RCM frame, named "<arm>_base", on an arm without a set-up joint."""
        ...

    def servo_jp(self, position: np.ndarray) -> None:
        """A joint position set-point (rad, rad, m) for the arm's joint PID, now; a stream of
        them follows a path."""
        ...

    def servo_jf(self, effort: np.ndarray) -> None:
        """Joint efforts (N m, N m, N) to the drives, now."""
        ...

    def move_jp(self, position: np.ndarray, wait: bool = True, timeout: float = 10.0) -> bool:
        """A smooth move to `position`; with `wait`, True once there and at rest, False
        when `timeout` s (of the rig clock) passed first."""
        ...

    def hold(self) -> None:
        """Hold the present position (the safe state)."""
        ...

    def power_on(self) -> None:
        """Enable the drives (the arm holds where it is); an arm already on stays as it is."""
        ...

    def published_rate(self) -> float:
        """Hz at which the arm publishes measured_js as its own clock stamps them; 0.0 when
        every tick of the rig clock has a fresh sample (an in-process arm)."""
        ...

    @property
    def supports_servo_ci(self) -> bool:
        """Whether the arm runs a Cartesian impedance of its own (`ImpedanceArm`)."""
        ...


@runtime_checkable
class ImpedanceArm(Arm, Protocol):
    """An arm that closes a Cartesian impedance in its own servo loop (the dVRK's servo_ci);
    an `Arm` whose `supports_servo_ci` is true has these too."""

    def measured_arm(self) -> tuple[np.ndarray, np.ndarray]:
        """The whole arm's newest measured positions and velocities, in the dVRK's order."""
        ...

    def servo_ci(self, position, orientation=None, stiffness=(0.0, 0.0, 0.0), damping=(0.0, 0.0, 0.0),
                 bias=(0.0, 0.0, 0.0), **torque) -> None:
        """A Cartesian impedance about the tool-tip goal `position` (m) and `orientation`
        (3x3), run by the arm in its own servo loop: per axis a spring `stiffness` (N/m),
        a damper `damping` (N s/m) and a `bias` (N); `torque`: the orientation's gains."""
        ...

    def servo_ci_problem(self) -> str | None:
        """None when `servo_ci` reaches the arm's servo loop (the message type can be built
        here and the arm's console takes it); else why not, as one line (no newline) that
        names the arm's servo_ci topic and what is missing (the message type here, or the
        console's subscription), for a procedure to refuse a slave with. It may wait a few
        seconds of wall time for the ROS graph (discovery), never longer."""
        ...


@runtime_checkable
class ForceSensor(Protocol):
    """A tension sensor between the tool tips."""

    #: where it is connected (its port), "" for the simulated one
    name: str

    def stream_age(self) -> float:
        """s since its driver last received a sample (the stream's own silence)."""
        ...

    def read(self) -> ForceSample:
        """The newest sample; raises if the stream is stale or disconnected."""
        ...

    def samples(self) -> list[ForceSample]:
        """Every sample received since the last call, oldest first."""
        ...

    def tare(self) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class Tracker(Protocol):
    """An optical motion-capture system."""

    def frames(self) -> list[TrackerFrame]:
        """Every frame received since the last call, oldest first, each once, a body that
        could not be tracked in a frame None in it. Raises a `rig.faults.DeviceFault`
        (`MocapStaleError`) once the stream has been silent for its stale timeout (s); the
        frames received before stay for the next call."""
        ...

    def latest(self) -> TrackerFrame:
        """The newest frame; raises as `frames` when the stream is stale, and before the
        first frame."""
        ...

    def close(self) -> None: ...

    #: the rigid bodies it tracks, by name
    bodies: tuple[str, ...] | list[str]

    #: its counters (frames, incomplete, late, dropped, ...): lost frames are reported, never hidden
    stats: object


@runtime_checkable
class Operator(Protocol):
    """Who does the steps of a procedure that need hands (drivers.operator.driver): a person at the
    console on the real rig, the simulation on the simulated one. Each call returns when done."""

    def confirm(self, message: str) -> None:
        """Do what `message` asks (mount bodies, clear the workspace)."""
        ...

    def detach_object(self) -> None:
        """Take the object (spring, suture) and the load cell off the tool tips."""
        ...

    def attach_object(self, kind: str | None = None) -> None:
        """Attach the object (`kind`: "spring" or "string"; None: the rig's) and the load cell
        between the tool tips."""
        ...

    def hang_mass(self, kg: float, element: int | None = None) -> None:
        """Hang `kg` kilograms from the load cell (0: take everything off it); `element`:
        which object element's cell, on a rig with one per element (None: the one cell).
        A mass that is not finite and >= 0 kg is refused (`OperatorError`)."""
        ...

    def touch(self, arms: dict, point_index: int, goal_world: np.ndarray) -> None:
        """Bring every arm's tool tip (its measured_cp, wrist straight) to one common
        physical point (the index-th, near `goal_world`: m in the world frame) and hold it
        there until the next command."""
        ...
