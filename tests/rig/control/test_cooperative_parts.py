"""The cooperative controller's parts, each on its own (rig.control: plan, tension estimate,
slack take-up, the object's elements, the master's lag, the slave strategies)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.control.arm_command import CommandKind
from rig.control.cooperative_gains import ForceLoop, Mode, SlaveControl, choice
from rig.control.cooperative_plan import Motion, Plan, UserOffsets, min_jerk
from rig.control.master_lag import JointEstimate
from rig.control.object_elements import ObjectElements, PairOffsets
from rig.control.slack_take_up import SlackTakeUp
from rig.control.slave_strategies import ArmSlave, EffortSlave, PositionSlave, strategy_for
from rig.control.tension_estimate import TensionEstimate


# -- the plan and the user's increments ---------------------------------------------------
def test_min_jerk_starts_and_ends_at_rest():
    assert min_jerk(0.0) == (0.0, 0.0, 0.0)
    p, v, a = min_jerk(1.0)
    assert p == pytest.approx(1.0) and v == pytest.approx(0.0) and a == pytest.approx(0.0, abs=1e-12)
    assert min_jerk(0.5)[0] == pytest.approx(0.5)
    assert min_jerk(-1.0) == min_jerk(0.0) and min_jerk(2.0) == min_jerk(1.0)


def test_the_plan_moves_every_tip_by_the_translation_and_keeps_their_distances():
    plan = Plan(Motion(np.array([0.05, 0.0, 0.0]), np.zeros(3), duration=2.0, start=1.0), ["A", "B"])
    x0 = {"A": np.array([0.4, 0.0, 0.0]), "B": np.array([0.5, 0.0, 0.0])}
    plan.start(10.0, x0)
    offsets = UserOffsets(0.01, 0.1, 2.0)
    xd, vd, _ = plan.desired(10.5, offsets)
    assert np.allclose(xd["A"], x0["A"]) and np.allclose(vd["B"], 0.0)
    xd, vd, _ = plan.desired(12.0, offsets)            # half way: half the move, the fastest
    assert np.allclose(xd["A"] - x0["A"], [0.025, 0, 0]) and vd["A"][0] == pytest.approx(1.875 * 0.05 / 2.0)
    xd, _, _ = plan.desired(20.0, offsets)
    assert np.allclose(xd["B"] - x0["B"], [0.05, 0, 0])
    assert np.linalg.norm(xd["B"] - xd["A"]) == pytest.approx(0.1)


def test_a_rotation_turns_the_tips_about_their_centroid():
    plan = Plan(Motion(np.zeros(3), np.array([0.0, 0.0, np.pi / 2]), duration=1.0, start=0.0), ["A", "B"])
    plan.start(0.0, {"A": np.array([0.4, 0.0, 0.0]), "B": np.array([0.6, 0.0, 0.0])})
    xd, _, _ = plan.desired(5.0, UserOffsets(0.01, 0.1, 2.0))
    assert np.allclose(xd["A"], [0.5, -0.1, 0.0]) and np.allclose(xd["B"], [0.5, 0.1, 0.0])


def test_an_increment_is_slewed_in_at_its_rate_not_stepped():
    off = UserOffsets(slew_translation=0.01, slew_rotation=0.1, slew_force=2.0)
    off.translation = np.array([0.001, 0.0, 0.0])
    off.force_offset = 1.0
    off.slew(0.05)                                    # 0.5 mm and 0.1 N in 50 ms
    assert off.applied_translation[0] == pytest.approx(0.0005) and off.velocity[0] == pytest.approx(0.01)
    assert off.applied_force == pytest.approx(0.1)
    for _ in range(20):
        off.slew(0.05)
    assert off.applied_translation[0] == pytest.approx(0.001) and off.applied_force == pytest.approx(1.0)
    off.slew(0.05)
    assert not off.velocity.any()


# -- the tension estimate -----------------------------------------------------------------
def test_the_estimate_follows_a_ramp_and_reads_its_rate():
    est = TensionEstimate(1, 0.002, 0.02)
    est.start(np.array([1.0]), None)
    for k in range(1, 1500):
        est.update(np.array([1.0 + 2.0 * 0.002 * k]), None, blind=False, dt_tick=0.002, timed=False)
    assert est.tension[0] == pytest.approx(1.0 + 2.0 * 0.002 * 1499, abs=0.01)
    assert est.tension_rate[0] == pytest.approx(2.0, rel=0.02)


def test_a_blind_estimate_holds_until_a_fresh_sample_and_then_restarts_from_it():
    est = TensionEstimate(1, 0.002, 0.02)
    est.start(np.array([3.0]), None)
    for _ in range(100):
        est.update(np.array([3.0]), None, blind=False, dt_tick=0.002, timed=False)
    held = est.tension.copy()
    assert est.update(np.array([9.0]), None, blind=True, dt_tick=0.002, timed=False)   # judged stale
    assert est.update(None, None, blind=False, dt_tick=0.002, timed=False)            # still nothing new
    assert est.tension == held and est.blind
    assert not est.update(np.array([5.0]), None, blind=False, dt_tick=0.002, timed=False)
    assert est.tension[0] == 5.0 and est.tension_rate[0] == 0.0 and not est.blind


def test_without_a_new_sample_the_estimate_predicts_over_the_tick():
    est = TensionEstimate(1, 0.01, 0.02)
    est.start(np.array([0.0]), np.array([0.0]))
    for k in range(1, 200):
        est.update(np.array([0.01 * k]), np.array([0.01 * k]), blind=False, dt_tick=0.01, timed=True)
    before = est.tension[0]
    est.update(None, None, blind=False, dt_tick=0.01, timed=True)
    assert est.tension[0] == pytest.approx(before + 0.01 * est.tension_rate[0], rel=0.05)


# -- the slack take-up and the set-point ramp ---------------------------------------------
def test_a_slack_object_holds_the_set_point_until_every_slave_is_taut_then_ramps():
    take_up = SlackTakeUp(["A", "B"], force=5.0, ramp_time=1.0, contact=0.5, scale_ramp=False)
    take_up.start(0.0, np.array([0.1, 0.2]), {"A": 0.1, "B": 0.2}, take_up=True)
    assert take_up.slack == {"A": True, "B": True} and take_up.ramp_start is None
    assert take_up.set_point(3.0, 0.0) == pytest.approx(0.15)
    take_up.taut("A", 1.0, {"A": 0.6, "B": 0.3})
    assert take_up.any_slack and take_up.ramp_start is None
    take_up.taut("B", 2.0, {"A": 0.8, "B": 0.6})
    assert take_up.ramp_start == 2.0 and take_up.initial_tension == pytest.approx(0.7)
    assert take_up.set_point(2.5, 0.0) == pytest.approx(0.7 + 0.5 * 4.3)
    assert take_up.set_point(9.0, 0.25) == pytest.approx(5.25)


def test_a_taut_object_ramps_at_once_and_taken_up_by_force_ramps_the_rest_faster():
    take_up = SlackTakeUp(["A"], force=5.0, ramp_time=1.0, contact=0.5, scale_ramp=True)
    take_up.start(1.0, np.array([4.0]), {"A": 4.0}, take_up=True)
    assert take_up.ramp_start == 1.0
    # 1 N of 5 left: the ramp takes 0.3 s (its floor), not 1 s
    assert take_up.set_point(1.3, 0.0) == pytest.approx(5.0)
    take_up.start(0.0, np.array([0.0]), {"A": 0.0}, take_up=False)     # position mode: never slack
    assert take_up.slack == {"A": False}


# -- the object's elements ----------------------------------------------------------------
TRIANGLE = [("A", "B"), ("A", "M"), ("B", "M")]


def test_a_slave_tracks_its_element_with_the_master_and_shares_the_pair():
    el = ObjectElements(TRIANGLE, "M", ["A", "B"])
    assert el.mine["A"] == [0, 1] and el.tracked["A"] == [1] and el.pairs["A"] == [0]
    assert el.tracked["B"] == [2] and el.pairs["B"] == [0]
    tips = {"A": np.array([0.0, 0.0, 0.0]), "B": np.array([0.1, 0.0, 0.0]), "M": np.array([0.05, 0.1, 0.0])}
    assert np.allclose(el.direction(0, "A", tips), [-1, 0, 0]) and np.allclose(el.direction(0, "B", tips), [1, 0, 0])
    u = el.outward("A", tips)
    assert np.linalg.norm(u) == pytest.approx(1.0) and np.allclose(u, -tips["M"] / np.linalg.norm(tips["M"]))
    assert len(el.neighbour_directions("A", tips)) == 2
    assert el.tracked_mean(np.array([1.0, 2.0, 3.0]), "B") == 3.0


def test_a_pair_offset_integrates_half_the_error_outside_the_deadband_within_its_limit():
    pairs = PairOffsets()
    pairs.integrate("A", 0, error=1.02, rate=0.0, k_i=0.1, deadband=0.02, k_damp=0.0, dt=0.1, limit=1.0)
    assert pairs.get("A", 0) == pytest.approx(0.5 * 0.1 * 1.0 * 0.1)
    pairs.integrate("A", 0, error=0.01, rate=0.0, k_i=0.1, deadband=0.02, k_damp=0.0, dt=0.1, limit=1.0)
    assert pairs.get("A", 0) == pytest.approx(0.005)
    for _ in range(100):
        pairs.integrate("A", 0, error=-50.0, rate=0.0, k_i=0.1, deadband=0.02, k_damp=0.0, dt=1.0, limit=0.03)
    assert pairs.get("A", 0) == -0.03 and pairs.get("B", 0) == 0.0


# -- the joints and the master's lag ------------------------------------------------------
def test_a_sample_seen_again_is_not_fed_twice():
    joints = JointEstimate(["A"], 0.002)
    q0 = np.array([0.1, 0.2, 0.1])
    assert joints.start(0.0, {"A": q0}, {"A": np.zeros(3)}, {"A": -0.001})
    q1 = q0 + 0.001
    qf1, _ = joints.update(0.002, {"A": q1}, {"A": np.zeros(3)}, {"A": 0.001})
    qf2, dqf2 = joints.update(0.004, {"A": q1}, {"A": np.zeros(3)}, {"A": 0.001})
    assert np.array_equal(qf1["A"], qf2["A"])
    # the sample's time on the loop's clock: its stamp plus the smallest offset seen (1 ms)
    assert joints.sample_time("A", 0.004) == pytest.approx(0.002)


# -- the strategies ---------------------------------------------------------------------
def test_one_strategy_per_mode_and_who_closes_the_impedance():
    assert isinstance(strategy_for(Mode.POSITION, SlaveControl.EFFORT), PositionSlave)
    assert isinstance(strategy_for(Mode.IMPEDANCE, SlaveControl.EFFORT), EffortSlave)
    assert isinstance(strategy_for(Mode.IMPEDANCE, SlaveControl.ARM), ArmSlave)
    assert choice(Mode, "position", "mode") is Mode.POSITION
    with pytest.raises(ValueError, match="mode must be 'impedance' or 'position', got 'force'"):
        choice(Mode, "force", "mode")
    assert CommandKind.EFFORT == "effort"


def _controller(mode="impedance", slave_control="effort", force=5.0):
    from rig.control.controllers import FeedforwardModel, StickSlipCompensation
    from rig.control.cooperative_controller import CooperativeController
    from rig.model import psm_kinematics as K
    from rig.model.psm_dynamics import PSMDynamics

    dyn = PSMDynamics()
    d = dyn.params.drive
    base = {"S": np.eye(4), "M": np.eye(4)}
    base["M"][:3, 3] = [0.0, 0.1, 0.0]
    frames = {n: T @ K.RCM_FRAME for n, T in base.items()}
    return CooperativeController(["S", "M"], "M", frames, {"S": FeedforwardModel(dyn, None)},
                                 {"S": StickSlipCompensation(d.Fc.copy(), d.Fv.copy(), d.Fo.copy(), d.slope)},
                                 [("S", "M")], force, dt=0.002, mode=mode, slave_control=slave_control,
                                 loop=ForceLoop())


def test_the_position_slave_steps_its_target_once_a_period_while_outside_the_deadband():
    c = _controller(mode="position")
    q = {n: np.array([0.0, 0.0, 0.12]) for n in ("S", "M")}
    zero = {n: np.zeros(3) for n in ("S", "M")}
    c.start(0.0, q, zero, np.array([1.0]))
    assert c.take_up.slack == {"S": False}
    steps = []
    for k in range(25):    # half way up the set-point's ramp (3 N against 1 N), 50 ms: three steps 20 ms apart
        cmds = c.step(0.5 + 0.002 * k, q, zero, np.array([1.0]))
        steps.append(c.x_f["S"])
        assert cmds["S"].kind == CommandKind.POSITION and cmds["M"].kind == CommandKind.POSITION
    assert steps[0] == pytest.approx(0.0002) and steps[9] == steps[0]
    assert steps[10] == pytest.approx(0.0004) and steps[20] == pytest.approx(0.0006)


def test_the_effort_slave_takes_up_a_slack_object_at_the_take_up_speed():
    c = _controller()
    q = {n: np.array([0.0, 0.0, 0.12]) for n in ("S", "M")}
    zero = {n: np.zeros(3) for n in ("S", "M")}
    c.start(0.0, q, zero, np.array([0.0]))
    assert c.take_up.slack == {"S": True}
    c.step(0.0, q, zero, np.array([0.0]))
    # standing still, x_f grows at take_up_gain x take_up_speed (m/s) over a tick
    assert c.x_f["S"] == pytest.approx(ForceLoop().take_up_gain * ForceLoop().take_up_speed * 0.002)
    cmds = c.step(0.002, q, zero, np.array([2.0]))
    assert not c.take_up.slack["S"] and c.take_up.ramp_start == 0.002
    assert cmds["S"].kind == CommandKind.EFFORT and cmds["S"].effort.shape == (3,)
