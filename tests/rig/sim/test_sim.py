import numpy as np
import pytest

from rig import config
from rig.model.plant_effects import HiddenEffects
from rig.model.psm_dynamics import PSMDynamics, PSMParameters, DriveParameters
from rig.sim.world import ArmSpec, ObjectSpec, SensorNoise, SimWorld, world_from_config


def _world(**kw):
    return world_from_config(config.load(), **kw)


def test_same_seed_same_run_different_seed_different_noise():
    a, b, c = _world(seed=7), _world(seed=7), _world(seed=8)
    for w in (a, b, c):
        w.servo_jp("PSM1", np.array([0.05, -0.05, 0.13]))
        w.advance(0.3)
    ma, mb, mc = a.measured_js("PSM1"), b.measured_js("PSM1"), c.measured_js("PSM1")
    assert all(np.array_equal(x, y) for x, y in zip(ma, mb))
    assert not np.array_equal(ma[1], mc[1])


def test_pid_step_settles():
    w = _world(with_object=False)
    w.advance(0.5)
    target = np.array([0.05, 0.05, 0.13])
    w.servo_jp("PSM1", target)
    err = []
    for _ in range(2000):
        w.step()
        err.append(np.abs(w.true_state("PSM1")[0] - target))
    err = np.array(err)
    assert np.all(err[-1] < [2e-3, 2e-3, 5e-4])
    # settled (within 10% of the step) after 1 s and stays there
    assert np.all(err[1000:] < 0.1 * np.array([0.05, 0.05, 0.01]))


def test_frictionless_unforced_plant_conserves_energy():
    params = PSMParameters(drive=DriveParameters(Fc=np.zeros(3), Fv=np.zeros(3), Fo=np.zeros(3)))
    spec = ArmSpec("A", params=params, noise=SensorNoise.off(), q0=np.array([0.3, 0.2, 0.12]))
    w = SimWorld([spec], dt=1e-4)
    w.power_off("A")
    w.set_state("A", np.array([0.3, 0.2, 0.12]), np.array([0.4, -0.3, 0.02]))
    dyn = PSMDynamics(params)
    e0 = dyn.energy(*w.true_state("A"))
    energies = []
    for _ in range(10):
        w.advance(0.1)
        energies.append(dyn.energy(*w.true_state("A")))
    drift = np.max(np.abs(np.array(energies) - e0))
    # symplectic Euler: bounded O(h) energy error, no secular drift
    assert drift < 2e-3 * max(1.0, abs(e0))
    assert np.ptp(w.true_state("A")[0]) > 0  # it did move


def test_effort_command_accelerates_as_the_model_says():
    spec = ArmSpec("A", noise=SensorNoise.off(), q0=np.array([0.0, 0.0, 0.12]))
    w = SimWorld([spec], dt=1e-4)
    dyn = PSMDynamics()
    q = np.array([0.0, 0.0, 0.12])
    tau = dyn.gravity_torque(q) + dyn.Fo + np.array([0.5, 0.0, 0.0]) + dyn.Fc * np.array([1, 0, 0])
    w.servo_jf("A", tau)
    w.advance(0.02)
    q1, dq1 = w.true_state("A")
    expected = dyn.forward_dynamics(q, np.array([1e-3, 0, 0]), tau)[0]
    assert dq1[0] / 0.02 == pytest.approx(expected, rel=0.15)
    assert dq1[0] > 0


def test_stiction_holds_below_breakaway_and_slips_above():
    effects = HiddenEffects(stiction=np.array([0.0, 0.0, 1.0]))
    spec = ArmSpec("A", effects=effects, noise=SensorNoise.off(), q0=np.array([0.0, 0.0, 0.12]))
    w = SimWorld([spec])
    dyn = PSMDynamics()
    g = dyn.gravity_torque(np.array([0.0, 0.0, 0.12]))
    hold = g + dyn.Fo
    w.advance(0.2)
    w.servo_jp("A", np.array([0.0, 0.0, 0.12]))
    w.advance(0.5)
    q0 = w.true_state("A")[0].copy()
    w.servo_jf("A", hold + np.array([0, 0, 0.9]))   # below Fs = 1 N
    w.advance(0.5)
    assert abs(w.true_state("A")[0][2] - q0[2]) < 1e-6
    w.servo_jf("A", hold + np.array([0, 0, 1.2]))   # above it: slips
    w.advance(0.2)
    assert w.true_state("A")[0][2] - q0[2] > 1e-3


@pytest.mark.parametrize("dt", [1e-3, 1e-4])
def test_coast_down_friction_follows_the_stribeck_law_at_any_step(dt):
    # Joint 3 pushed, then left to its friction (gravity and offset held): each step's
    # deceleration times the mass is Fc + Fv v + (Fs - Fc) exp(-(v/vs)^2) at the velocity
    # the step ends with, at the dVRK's 1 kHz as at 10 kHz.
    dyn = PSMDynamics()
    q0 = np.array([0.0, 0.0, 0.10])
    excess, vs = 0.8, 0.006
    effects = HiddenEffects(stiction=np.array([0, 0, dyn.Fc[2] + excess]), stribeck_velocity=np.array([0.01, 0.01, vs]))
    w = SimWorld([ArmSpec("A", noise=SensorNoise.off(), effects=effects, q0=q0)], dt=dt)
    hold = dyn.gravity_torque(q0) + dyn.Fo
    w.servo_jf("A", hold + np.array([0, 0, 3.0]))
    w.advance(0.03)
    w.servo_jf("A", hold)
    v = []
    for _ in range(int(0.2 / dt)):
        w.step()
        v.append(w.true_state("A")[1][2])
    v = np.array(v)
    a = np.diff(v) / dt
    v = v[1:]
    sel = (v > 0.002) & (v < 0.012)
    assert sel.sum() >= 10
    measured = -dyn.mass_matrix(q0)[2, 2] * a[sel] - dyn.Fc[2] - dyn.Fv[2] * v[sel]
    assert np.abs(measured - excess * np.exp(-(v[sel] / vs) ** 2)).max() < 0.01


def test_spring_object_tension_is_stiffness_times_stretch():
    w = _world()
    p1, p2 = w.tip_world("PSM1"), w.tip_world("PSM2")
    assert np.linalg.norm(p2 - p1) == pytest.approx(0.10, abs=1e-9)
    # pull PSM2's tip 5 mm away along the object and hold both
    q2 = w.true_state("PSM2")[0]
    q2[2] += 0.0  # insertion unchanged
    w.servo_jp("PSM2", q2 + np.array([0.05, 0, 0]))
    w.advance(1.0)
    length = np.linalg.norm(w.tip_world("PSM2") - w.tip_world("PSM1"))
    assert w.tension() == pytest.approx(2450.0 * (length - 0.10), abs=0.05)


def test_string_goes_slack_and_pulls_only():
    cfg = config.parse({"object": {"kind": "string", "stiffness": 20000.0, "rest_length": 0.12}}, "t")
    w = world_from_config(cfg)
    w.advance(0.1)
    assert w.tension() == 0.0
    cfg = config.parse({"object": {"kind": "string", "stiffness": 20000.0, "rest_length": 0.095}}, "t")
    w = world_from_config(cfg)
    w.advance(0.5)
    assert w.tension() > 1.0


def test_three_arms_hold_a_triangle_of_elements():
    doc = {"arms": {"PSM1": {}, "PSM2": {"base_xyz": [1.0728, 0, 0], "base_rpy": [0, 0, np.pi]},
                    "PSM3": {"base_xyz": [0.5364, 0.5730, 0], "base_rpy": [0, 0, -np.pi / 2]}},
           "object": {"arms": ["PSM1", "PSM2", "PSM3"], "rest_length": 0.098}}
    w = world_from_config(config.parse(doc, "t"))
    assert w.object_elements == [("PSM1", "PSM2"), ("PSM1", "PSM3"), ("PSM2", "PSM3")]
    lengths = [np.linalg.norm(w.tip_world(b) - w.tip_world(a)) for a, b in w.object_elements]
    assert np.allclose(lengths, 0.10, atol=2e-4)  # an equilateral triangle of tips
    w.advance(1.0)
    assert all(2.0 < w.tension(i) < 6.0 for i in range(3))


def test_backlash_separates_encoder_from_joint():
    effects = HiddenEffects(backlash=np.array([0.0, 0.0, 0.002]))
    spec = ArmSpec("A", effects=effects, noise=SensorNoise.off())
    w = SimWorld([spec])
    w.advance(0.3)
    for target in (0.14, 0.12):
        w.servo_jp("A", np.array([0.0, 0.0, target]))
        w.advance(0.6)
    # after reversing, the encoder (motor side) and the joint differ by up to half the play
    diff = w.qm[2] - w.q[2]
    assert 2e-4 < abs(diff) <= 0.0011


def _backlash_stroke(joint: int, play: float, amp: float, seconds: float = 4.0):
    """Joint ``joint`` (0-based) with a play driven through sin^2 strokes of ``amp``: the
    motor-minus-joint offset and relative velocity at every 1 ms step."""
    b = np.zeros(3)
    b[joint] = play
    w = SimWorld([ArmSpec("A", effects=HiddenEffects(backlash=b), noise=SensorNoise.off())])
    w.advance(0.3)
    q0 = w.qm[:3].copy()
    d, rel = [], []
    for k in range(int(round(seconds / w.dt))):
        t = k * w.dt
        target, rate = q0.copy(), np.zeros(3)
        target[joint] += amp * np.sin(np.pi * t) ** 2
        rate[joint] = amp * np.pi * np.sin(2 * np.pi * t)
        w.servo_jp("A", target, rate)
        w.step()
        d.append(w.qm[joint] - w.q[joint])
        rel.append(w.dqm[joint] - w.dq[joint])
    return np.array(d), np.array(rel)


def test_backlash_contact_does_not_chatter():
    # Gravity keeps the insertion joint loaded on one side of its play: the contact must hold
    # still (an explicit step of the contact damping, c h / Im > 1, made the sides bounce).
    d, rel = _backlash_stroke(2, 0.002, 0.03)
    assert np.all(np.abs(d) > 0.001)
    assert np.sqrt(np.mean(rel ** 2)) < 2e-3


def test_backlash_reversal_crosses_the_whole_play():
    # The yaw joint's transmitted torque reverses: the motor side travels across the play
    # (lost motion) and presses on the other side, with only the contact's small stretch beyond.
    play = 0.01
    d, _ = _backlash_stroke(0, play, 0.3)
    assert d.min() < -0.5 * play and d.max() > 0.5 * play
    assert play <= d.max() - d.min() <= 1.1 * play


def test_effort_delay_shifts_the_measured_effort():
    effects = HiddenEffects(time_delay=0.02)
    w = SimWorld([ArmSpec("A", effects=effects, noise=SensorNoise.off())])
    w.servo_jf("A", np.array([0.0, 0.0, 0.0]))
    w.advance(0.05)
    w.servo_jf("A", np.array([0.3, 0.0, 0.0]))
    w.advance(0.01)
    assert w.measured_js("A")[2][0] == 0.0
    w.advance(0.011)
    assert w.measured_js("A")[2][0] == pytest.approx(0.3)


def test_payload_changes_the_true_plant():
    heavy = SimWorld([ArmSpec("A", effects=HiddenEffects(payload_mass=0.3), noise=SensorNoise.off())])
    light = SimWorld([ArmSpec("A", noise=SensorNoise.off())])
    for w in (heavy, light):
        w.servo_jp("A", np.array([0.0, 0.0, 0.12]))
        w.advance(1.0)
    # holding the insertion against gravity takes about m g more effort
    extra = heavy.setpoint_js("A")[2][2] - light.setpoint_js("A")[2][2]
    assert extra == pytest.approx(-0.3 * 9.81, rel=0.05)


def test_measurement_noise_and_quantisation():
    w = SimWorld([ArmSpec("A")], seed=2)
    w.advance(0.5)
    v = np.array([w.measured_js("A")[1] for _ in range(2000)])
    assert v.std(axis=0) == pytest.approx(SensorNoise().velocity_noise, rel=0.1)
    q = w.measured_js("A")[0]
    assert np.allclose(q / SensorNoise().position_quantum, np.round(q / SensorNoise().position_quantum))


def test_object_needs_known_arms():
    with pytest.raises(ValueError, match="PSM9"):
        SimWorld([ArmSpec("PSM1"), ArmSpec("PSM2")], ObjectSpec(arms=("PSM1", "PSM9")))


def test_pacing_to_the_wall_clock():
    import time

    w = SimWorld([ArmSpec("A")], pace=True)
    t0 = time.perf_counter()
    w.advance(0.2)
    # Never ahead of the wall clock: the pace starts at the first step, so 200 steps of 1 ms
    # take at least 199 ms (less 9 ms of slack). Only a lower bound: a loaded machine is
    # slower, never faster; without pacing the steps take a few ms.
    assert time.perf_counter() - t0 >= 0.19


def test_spring_and_offset_loads_show_in_the_holding_effort():
    base = SimWorld([ArmSpec("A", noise=SensorNoise.off())])
    sprung = SimWorld([ArmSpec("A", noise=SensorNoise.off(),
                               effects=HiddenEffects(spring=np.array([0.0, 0.0, 50.0]),
                                                     torque_offset=np.array([0.3, 0.0, 0.0])))])
    for w in (base, sprung):
        w.advance(2.0)
    diff = sprung.setpoint_js("A")[2] - base.setpoint_js("A")[2]
    # spring: k (q3 - 0) = 50 N/m * 0.12 m = 6 N; offset: 0.3 N m on joint 1. A joint at
    # rest may hold anywhere within its Coulomb band, so each figure is known to +/- 2 Fc.
    fc = PSMDynamics().Fc
    assert diff[2] == pytest.approx(6.0, abs=2 * fc[2])
    assert diff[0] == pytest.approx(0.3, abs=2 * fc[0])


def test_direction_dependent_and_position_dependent_coulomb():
    # Drive joint 3 at constant speed both ways with the PID; the effort difference between
    # the directions is 2 Fc (+ asymmetry); with position friction it varies along the stroke.
    def sweep(effects):
        w = SimWorld([ArmSpec("A", noise=SensorNoise.off(), effects=effects, q0=np.array([0, 0, 0.05]))])
        w.advance(0.3)
        out = {}
        for sign, (a, b) in ((+1, (0.05, 0.20)), (-1, (0.20, 0.05))):
            efforts, qs = [], []
            for k in range(3000):
                q3 = a + (b - a) * k / 2999
                w.servo_jp("A", np.array([0, 0, q3]), np.array([0, 0, (b - a) / 3.0]))
                w.step()
                if 500 < k < 2500:
                    efforts.append(w.setpoint_js("A")[2][2])
                    qs.append(w.true_state("A")[0][2])
            out[sign] = (np.array(qs), np.array(efforts))
        return out

    plain = sweep(HiddenEffects())
    asym = sweep(HiddenEffects(coulomb_asymmetry=np.array([0, 0, 0.4])))
    gap_plain = plain[1][1].mean() - plain[-1][1].mean()
    gap_asym = asym[1][1].mean() - asym[-1][1].mean()
    # the asymmetric joint's up-stroke needs +0.2 N more and its down-stroke 0.2 N less... in
    # sum the level difference shows as a shift of the mean of the two strokes
    shift = (asym[1][1].mean() + asym[-1][1].mean()) - (plain[1][1].mean() + plain[-1][1].mean())
    assert shift == pytest.approx(0.4, abs=0.08)
    assert gap_asym == pytest.approx(gap_plain, abs=0.08)
    posf = sweep(HiddenEffects(position_friction=np.array([0, 0, 0.5])))
    q, e = posf[1]
    resid = e - np.polyval(np.polyfit(q, e, 1), q)
    corr = np.corrcoef(resid, np.sin(2 * np.pi * q / 0.08))[0, 1]
    assert corr > 0.8
