"""What every implementation of an interface does (drivers/interfaces.py), one check per promise.

tests/drivers/test_conformance.py runs them over the in-process twins and the drivers that
need no ROS (the NatNet tracker against its fake Motive), tests/drivers/test_conformance_ros.py
over the ROS drivers against `rig sim --sim-time`: the same function, the same numbers, so a
twin cannot drift from its driver without one of them failing. A check moves time only by
`rig.clock.tick()` (or an arm's own waits on its clock): the simulated world's clock in
process, `rig sim`'s /clock in lockstep over the wire, so no figure depends on how fast the
machine is.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.arm.crtk import ARRIVAL_TOLERANCE
from drivers.interfaces import Arm, ImpedanceArm, JointState, Operator, Pose, Tracker, TrackerFrame

#: rad, rad, m: the servo_jp step the arm checks command (small, well inside the workspace)
STEP = np.array([0.05, -0.04, 0.01])
#: rad, rad, m a resting arm may drift in the checks' 0.2 s (encoder quanta, the PID's settling)
AT_REST = np.array([2e-3, 2e-3, 5e-4])


def run_for(rig, seconds: float, each=None) -> None:
    """Tick the rig's clock for `seconds` of its time, calling `each()` before every tick."""
    for _ in range(int(round(seconds * rig.clock.rate))):
        if each is not None:
            each()
        rig.clock.tick()


def settle(rig) -> None:
    """The rig as the checks start it: the object off the tool tips (its pull would make the
    arms' resting positions and a touch the object's, not the interface's), every arm on and
    at rest."""
    rig.operator.detach_object()
    for arm in rig.arms.values():
        arm.power_on()
        arm.hold()
    run_for(rig, 0.3)


# -- Arm ----------------------------------------------------------------------------------
def check_arm_kind(arm, impedance: bool) -> None:
    """An Arm, and an ImpedanceArm exactly when it says it runs servo_ci (supports_servo_ci)."""
    assert isinstance(arm, Arm)
    assert arm.supports_servo_ci is impedance
    assert isinstance(arm, ImpedanceArm) is impedance
    assert arm.published_rate() >= 0.0


def check_servo_jp_and_drain(rig, name: str) -> None:
    """A stream of servo_jp moves the measured joints to the command (the true plant's PID);
    setpoint_js says the command; draining on every tick hands over every sample once,
    oldest first, the newest the one measured_js gives, at the rate published_rate() says."""
    arm = rig.arms[name]
    q0 = arm.measured_js().position[:3].copy()
    target = q0 + STEP
    arm.drain_js()
    samples: list[JointState] = []
    ticks = 0
    for _ in range(int(round(0.6 * rig.clock.rate))):
        arm.servo_jp(target)
        rig.clock.tick()
        ticks += 1
        samples += arm.drain_js()
    js = arm.measured_js()
    q = js.position[:3]
    assert np.all(np.abs(q - target) < 0.25 * np.abs(STEP)), f"{name}: from {q0} toward {target}, at {q}"
    assert np.allclose(arm.setpoint_js().position[:3], target, atol=1e-9)
    t = np.array([s.t for s in samples])
    assert len(samples) >= ticks, f"{len(samples)} samples in {ticks} ticks: every tick has a fresh one"
    assert np.all(np.diff(t) > 0), "oldest first, each once"
    assert t[-1] == pytest.approx(js.t, abs=1e-9), "the newest drained sample is measured_js's"
    rate = arm.published_rate() or rig.clock.rate
    assert float(np.median(np.diff(t))) == pytest.approx(1.0 / rate, rel=0.05), "published_rate() is the stamps'"
    assert arm.move_jp(q0, wait=True, timeout=5.0)


def check_power_on_and_hold(rig, name: str) -> None:
    """power_on on an arm that is on leaves it where it is; hold keeps it there."""
    arm = rig.arms[name]
    run_for(rig, 0.05)
    q0 = arm.measured_js().position[:3].copy()
    arm.power_on()
    run_for(rig, 0.2)
    q1 = arm.measured_js().position[:3]
    assert np.all(np.abs(q1 - q0) < AT_REST), f"{name} moved on power_on: {q0} -> {q1}"
    arm.hold()
    run_for(rig, 0.2)
    q2 = arm.measured_js().position[:3]
    assert np.all(np.abs(q2 - q0) < AT_REST), f"{name} moved on hold: {q0} -> {q2}"


def tool_tip(q: np.ndarray) -> np.ndarray:
    """The dVRK's tool tip (4x4, the large needle driver, wrist straight) in the RCM frame."""
    from rig.model.psm_arm_kinematics import PSMKinematics

    return PSMKinematics().forward(np.concatenate([np.asarray(q, float)[:3], np.zeros(3)]))


def check_move_jp_and_measured_cp(rig, name: str) -> None:
    """move_jp(wait) arrives at rest on its goal and says so; measured_cp is then the tool
    tip of the measured joints, in the arm's base frame as the interface names it."""
    arm = rig.arms[name]
    q0 = arm.measured_js().position[:3].copy()
    goal = q0 + np.array([-0.06, 0.05, -0.012])
    assert arm.move_jp(goal, wait=True, timeout=5.0) is True
    run_for(rig, 0.05)
    q = arm.measured_js().position[:3]
    assert np.all(np.abs(q - goal) <= ARRIVAL_TOLERANCE), f"{name} move_jp ended at {q}, goal {goal}"
    cp = arm.measured_cp()
    assert isinstance(cp, Pose) and cp.frame == f"{name}_base"
    T = tool_tip(arm.measured_js().position)
    assert np.allclose(cp.position, T[:3, 3], atol=5e-4), (cp.position, T[:3, 3])
    assert np.allclose(cp.rotation, T[:3, :3], atol=5e-3)
    assert arm.move_jp(q0, wait=True, timeout=5.0)


# -- Tracker ------------------------------------------------------------------------------
class BodyTruth:
    """Where the rig's marker bodies are for given joints of its arms, on the configured
    placement (what `rig sim` serves), solved without noise as a tracker does. `at(t)`: body
    -> (R, p, centre of its markers in the body frame) with each arm at its measured joints
    of time t (s), from the samples `record` took."""

    def __init__(self, cfg, names: list[str]):
        from rig.sim.world import world_from_config

        self.world = world_from_config(cfg, arms=list(names), seed=0, with_object=False)
        self.layouts = {mb.name: np.asarray(mb.offsets, float) for mb in self.world.marker_bodies}
        self.samples: dict[str, list[JointState]] = {n: [] for n in names}

    def record(self, arms: dict) -> None:
        """Drain every arm's samples (call it every tick)."""
        for n, arm in arms.items():
            self.samples[n] += arm.drain_js()

    def at(self, t: float) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        from drivers.mocap.sim import kabsch

        for n, got in self.samples.items():
            stamps = np.array([s.t for s in got])
            k = int(np.clip(np.searchsorted(stamps, t + 1e-9) - 1, 0, len(got) - 1))
            self.world.set_state(n, np.asarray(got[k].position, float)[:3])
        markers = self.world.marker_positions()
        out = {}
        for b, layout in self.layouts.items():
            R, p, _ = kabsch(layout, markers[b])
            out[b] = (R, p, layout.mean(axis=0))
        return out


def collect_frames(rig, tracker, seconds: float, truth: BodyTruth) -> list[TrackerFrame]:
    """Tick for `seconds`, recording the arms' samples into `truth`; the frames delivered."""
    tracker.frames()
    truth.record(rig.arms)
    got: list[TrackerFrame] = []
    for _ in range(int(round(seconds * rig.clock.rate))):
        rig.clock.tick()
        truth.record(rig.arms)
    got += tracker.frames()
    return got


def check_tracker_frames(tracker, frames: list[TrackerFrame], rate: float, occlusion: float,
                         truth: BodyTruth, stamp=lambda f: f.t) -> None:
    """`frames`: what frames() handed over; `stamp(frame)`: its capture time on the world's
    clock (s; its `t`, where the tracker stamps on that clock). Oldest first, each once, at
    the tracker's rate; every tracked body in every frame, None where it was occluded (about
    `occlusion` of the time), else where the rig's kinematics put it: the centre of its
    markers within marker noise, its orientation within the solve's (a body's origin may sit
    a lever arm away from its markers, where the orientation's noise moves it mm)."""
    assert isinstance(tracker, Tracker)
    assert len(frames) >= 50
    t = np.array([stamp(f) for f in frames])
    assert np.all(np.diff(t) > 0), "oldest first, each once"
    assert float(np.median(np.diff(t))) == pytest.approx(1.0 / rate, rel=0.1)
    bodies = set(tracker.bodies)
    seen = lost = 0
    for f in frames:
        assert set(f.bodies) == bodies, f"frame at {f.t}: {sorted(f.bodies)} not {sorted(bodies)}"
        true = truth.at(stamp(f))
        for b, pose in f.bodies.items():
            if pose is None:
                lost += 1
                continue
            seen += 1
            if b in true:
                R, p, c = true[b]
                centre = pose.rotation @ c + pose.position
                assert np.linalg.norm(centre - (R @ c + p)) < 1.5e-3, (b, centre, R @ c + p)
                assert np.allclose(pose.rotation @ R.T, np.eye(3), atol=0.05), b
    assert lost / (seen + lost) == pytest.approx(occlusion, abs=0.05), f"{lost} of {seen + lost} bodies lost"
    assert tracker.latest().t >= frames[-1].t


# -- Operator -----------------------------------------------------------------------------
def check_touch(rig, names: list[str], rcm_world: dict[str, np.ndarray]) -> None:
    """touch brings every named arm's tool tip (measured_cp) onto one point near the goal;
    `rcm_world`: each arm's true RCM frame in the world (4x4)."""
    op = rig.operator
    assert isinstance(op, Operator)
    q0 = {n: rig.arms[n].measured_js().position[:3].copy() for n in names}
    tips = [rcm_world[n] @ tool_tip(q0[n])[:, 3] for n in names]
    goal = np.mean(tips, axis=0)[:3]
    op.touch({n: rig.arms[n] for n in names}, 0, goal)
    # read at once (two ticks): rig sim pins touching tips until the next command, the
    # in-process twin leaves them to the arm's PID, which lets them sag (2.5 mm in 50 ms)
    run_for(rig, 0.004)
    for n in names:
        cp = rig.arms[n].measured_cp()
        tip = (rcm_world[n] @ np.append(cp.position, 1.0))[:3]
        assert np.linalg.norm(tip - goal) < 1e-3, f"{n}'s tool tip at {tip}, the touch point {goal}"
    for n in names:  # back where they were (a command ends the touch's hold)
        assert rig.arms[n].move_jp(q0[n], wait=True, timeout=5.0)


def check_operator_refuses(op) -> None:
    """A mass no person can hang is refused in one line, whoever the operator is."""
    from drivers.operator.driver import OperatorError

    for kg in (-0.1, float("nan")):
        with pytest.raises(OperatorError) as err:
            op.hang_mass(kg)
        assert "kg" in str(err.value) and "\n" not in str(err.value)
