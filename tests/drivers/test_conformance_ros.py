"""The ROS drivers against `rig sim --sim-time`, through the same behaviour checks as their
twins (tests/drivers/conformance_checks.py, tests/drivers/test_conformance.py): RosArm
against the console's PSM that rig sim serves (FakePSM behind FakeArmState), RosMocapTracker
against its mocap bridge (FakeRosMocap), RosOperator against its side channel
(FakeOperatorServer).

One `rig sim --sim-time` serves the module from a lab's rig.toml (ROS arms and mocap with
occluding bodies, rig sim's operator, `[ros] use_sim_time`) on a ROS domain claimed for it
(tests/hil/harness.py); this process opens the rig as a procedure does
(`rig.devices.factory.open_rig`), so every check ticks the rig's `SimTimeClock` in lockstep
with the world: what a check sees does not depend on how busy the machine is. Each test
leaves the arms where it found them, so the tests pass in any order.
"""

from __future__ import annotations

import pytest

import rclpy  # noqa: F401  (a declared dependency: a broken install fails here)

from drivers.arm.dvrk_arm import RosArm
from drivers.mocap.ros_tracker import RosMocapTracker
from drivers.operator.driver import RosOperator
from rig.model import psm_kinematics as K
from tests.drivers import conformance_checks as checks
from tests.hil.harness import ServedRig, lab_toml
from tests.ros_domains import ros_environment

pytestmark = pytest.mark.ros

#: the probability a served body is occluded in a frame (as tests/drivers/test_conformance.py's)
OCCLUSION = 0.2


def _toml(folder, extra: str = "") -> str:
    text = lab_toml(folder, sim_time=True, extra=extra)
    return text.replace('[mocap]\ndriver = "ros"\n', f'[mocap]\ndriver = "ros"\nocclusion = {OCCLUSION}\n')


def _open(served: ServedRig, uses=("mocap",)):
    from rig import config
    from rig.devices.factory import open_rig

    cfg = config.load(served.folder / "rig.toml")
    rig = open_rig(cfg, ["PSM1", "PSM2"], uses=uses, say=lambda line: None,
                   arm_streams=("measured_js", "setpoint_js", "measured_cp"))
    return cfg, rig


@pytest.fixture(scope="module")
def wire(tmp_path_factory):
    """(cfg, rig): the module's rig sim and the rig opened on it, the object off the tips."""
    folder = tmp_path_factory.mktemp("lab")
    with ServedRig(folder, toml=_toml(folder), sim_args=("--ros-period", "0.001", "--no-loadcell"),
                   sim_time=True) as served, ros_environment(served.domain):
        cfg, rig = _open(served)
        try:
            checks.settle(rig)
            yield cfg, rig
        finally:
            rig.close()


def test_the_ros_arm_does_what_the_interface_says(wire):
    _, rig = wire
    arm = rig.arms["PSM1"]
    assert isinstance(arm, RosArm)
    checks.check_arm_kind(arm, impedance=True)
    assert arm.published_rate() > 0.0  # a stream over the wire (its rate: check_servo_jp_and_drain)
    checks.check_servo_jp_and_drain(rig, "PSM1")
    checks.check_power_on_and_hold(rig, "PSM2")
    checks.check_move_jp_and_measured_cp(rig, "PSM1")
    # the console serves servo_ci (rig sim without --no-servo-ci): nothing stands in its way
    assert arm.servo_ci_problem() is None


def test_the_ros_tracker_does_what_the_interface_says(wire):
    cfg, rig = wire
    assert isinstance(rig.tracker, RosMocapTracker)
    truth = checks.BodyTruth(cfg, list(rig.arms))
    frames = checks.collect_frames(rig, rig.tracker, 1.0, truth)
    checks.check_tracker_frames(rig.tracker, frames, cfg.mocap["rate"], OCCLUSION, truth)


def test_the_ros_operator_does_what_the_interface_says(wire):
    cfg, rig = wire
    assert isinstance(rig.operator, RosOperator)
    checks.check_touch(rig, ["PSM1", "PSM2"], {n: cfg.base_matrix(n) @ K.RCM_FRAME for n in rig.arms})
    checks.check_operator_refuses(rig.operator)


@pytest.mark.slow  # a rig sim of its own (its mocap cable is pulled for good), ~15 s
def test_a_ros_tracker_whose_cable_is_pulled_goes_stale_as_the_twin(tmp_path):
    from rig.faults import DeviceFault

    folder = tmp_path / "lab"
    with ServedRig(folder, toml=_toml(folder), sim_args=("--ros-period", "0.001", "--no-loadcell"),
                   sim_time=True) as served, ros_environment(served.domain):
        cfg, rig = _open(served)
        try:
            tracker = rig.tracker
            checks.run_for(rig, 0.1)
            tracker.frames()
            rig.operator.unplug("mocap")
            checks.run_for(rig, 0.5 * tracker.stale_timeout)
            tracker.frames()  # not yet
            checks.run_for(rig, 0.6 * tracker.stale_timeout + 0.05)
            for read in (tracker.frames, tracker.latest):
                with pytest.raises(DeviceFault, match="stale") as err:
                    read()
                assert "\n" not in str(err.value)
        finally:
            rig.close()


@pytest.mark.slow  # a rig sim of its own, ~10 s
def test_servo_ci_problem_names_the_topic_on_a_console_that_does_not_serve_it(tmp_path):
    folder = tmp_path / "lab"
    with ServedRig(folder, toml=_toml(folder), sim_args=("--ros-period", "0.001", "--no-loadcell", "--no-servo-ci"),
                   sim_time=True) as served, ros_environment(served.domain):
        _, rig = _open(served, uses=())
        try:
            arm = rig.arms["PSM1"]
            assert arm.supports_servo_ci  # the message type loads here: the console is what lacks
            problem = arm.servo_ci_problem()
            assert problem is not None and "\n" not in problem
            assert problem.startswith("/PSM1/servo_ci: the console does not subscribe to it"), problem
        finally:
            rig.close()
