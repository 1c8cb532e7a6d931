"""A model file as the simulated arm's plant (issue 7: "adds it to the model" that the
simulated rig can use): `IdentifiedModel.plant`, the arm key `plant_model`, `rig sim
--plant-model`, and the sim physics the mapping needs (friction profile, damping exponent,
per-joint effort delay, motor-side inertia of a play)."""

import json

import numpy as np
import pytest

from rig import config
from rig.model.model_file import ModelFileError, load_model, save_model
from rig.model.plant_effects import HiddenEffects
from rig.model.psm_dynamics import PSMDynamics, PSMParameters
from rig.sim.world import ArmSpec, SensorNoise, SimWorld, world_from_config

NOMINAL = PSMParameters()
FC = NOMINAL.drive.Fc


def _model_file(path, effects, stribeck=None):
    return load_model(save_model(path, standard=NOMINAL.standard_vector(), names=PSMDynamics.param_names(),
                                 slope=400.0, gravity=[0.0, 0.0, -9.81], stribeck=stribeck,
                                 extra={"effects": effects}))


def _efforts(params, effects, seconds=1.5):
    """Measured efforts (n, 3) of one arm whose PID follows a multi-sine on every joint."""
    w = SimWorld([ArmSpec("A", params=params, effects=effects, noise=SensorNoise.off(),
                          q0=np.array([0.0, 0.0, 0.12]))], seed=3)
    out = []
    for k in range(int(seconds / w.dt)):
        t = k * w.dt
        w.servo_jp("A", np.array([0.3 * np.sin(2.1 * t), 0.25 * np.sin(1.7 * t + 0.4), 0.12 + 0.05 * np.sin(3.3 * t)]),
                   np.array([0.63 * np.cos(2.1 * t), 0.425 * np.cos(1.7 * t + 0.4), 0.165 * np.cos(3.3 * t)]))
        w.step()
        out.append(w.measured_js("A")[2])
    return np.array(out)


def test_model_file_effects_become_the_same_sim_physics(tmp_path):
    # Each catalogue entry, written as `rig discrepancy` writes it, gives the plant the
    # physics the sim's own hidden effects would: the recorded efforts agree to rounding.
    k_ripple, period = 0.5, 0.08
    entries = [
        {"name": "spring", "joint": 1, "params": {"k": 0.8, "q0": 0.1}},
        {"name": "torque_offset", "joint": 2, "params": {"offset": 0.15}},
        {"name": "hysteresis", "joint": 3, "params": {"Fd": 0.6, "travel": 0.001, "sigma0": 600.0}},
        {"name": "viscous_nonlinear", "joint": 2, "params": {"c": 0.7, "exponent": 2.0}},
        # catalogue 1.1's single ripple (amplitude, phase) on the Coulomb level Fc
        {"name": "position_friction", "joint": 3, "params": {"amplitude": k_ripple * FC[2], "phase": 0.0,
                                                            "period": period}},
        {"name": "stiction", "joint": 1, "params": {"dFs": 0.2, "Fs": FC[0] + 0.2, "Fc": FC[0], "vs": 0.02}},
        {"name": "backlash", "joint": 1, "params": {"width": 0.01, "motor_inertia": 0.03}},
        {"name": "time_delay", "joint": 2, "params": {"delay": 0.01, "gain": 1.0, "grid_delay": 0.01}},
    ]
    params, effects = _model_file(tmp_path / "m.json", entries).plant()
    truth = HiddenEffects(spring=np.array([0.8, 0, 0]), spring_rest=np.array([0.1, 0, 0]),
                          torque_offset=np.array([0, 0.15, 0]), hysteresis=np.array([0, 0, 0.6]),
                          hysteresis_stiffness=np.array([40.0, 40.0, 600.0]),
                          viscous_nonlinear=np.array([0, 0.7, 0]),
                          position_friction=np.array([0, 0, k_ripple]),
                          position_friction_period=np.array([0.8, 0.6, period]),
                          stiction=np.array([FC[0] + 0.2, 0, 0]), stribeck_velocity=np.array([0.02, 0.01, 0.01]),
                          backlash=np.array([0.01, 0, 0]), backlash_motor_inertia=np.array([0.03, np.nan, np.nan]),
                          time_delay=np.array([0.0, 0.01, 0.0]))
    got, want = _efforts(params, effects), _efforts(NOMINAL, truth)
    np.testing.assert_allclose(got, want, atol=1e-8)
    bare = _efforts(NOMINAL, HiddenEffects())
    assert np.all(np.sqrt(((want - bare) ** 2).mean(0)) > [0.05, 0.05, 0.3])   # the effects do show


def test_friction_profile_and_damping_exponent_in_the_plant(tmp_path):
    # Joint 3 swept at constant speed: the effort over the profile-free plant's is the
    # profile sigma(dq) f(q) of two harmonics; a damping exponent of 3 shows as c |dq|^3.
    a_sin, a_cos, period = [0.2, -0.1], [0.05, 0.12], 0.1
    entries = [{"name": "position_friction", "joint": 3,
                "params": {"period": period, "harmonics": 2, "a_sin": a_sin, "a_cos": a_cos}},
               {"name": "viscous_nonlinear", "joint": 3, "params": {"c": 30.0, "exponent": 3.0}}]
    params, effects = _model_file(tmp_path / "m.json", entries).plant()
    np.testing.assert_array_equal(effects.friction_profile_sin[2, :2], a_sin)
    assert effects.viscous_exponent[2] == 3.0

    def sweep(eff, speed):
        w = SimWorld([ArmSpec("A", effects=eff, noise=SensorNoise.off(), q0=np.array([0, 0, 0.05]))])
        w.advance(0.3)
        n = int(round(0.15 / speed / w.dt))
        qs, es = [], []
        for k in range(n):
            w.servo_jp("A", np.array([0, 0, 0.05 + speed * k * w.dt]), np.array([0, 0, speed]))
            w.step()
            if k > n // 6:
                qs.append(w.true_state("A")[0][2])
                es.append(w.setpoint_js("A")[2][2])
        return np.array(qs), np.array(es)

    only_profile = HiddenEffects(**{k: getattr(effects, k) for k in
                                    ("friction_profile_period", "friction_profile_sin", "friction_profile_cos")})
    q, e = sweep(only_profile, 0.05)
    _, e0 = sweep(HiddenEffects(), 0.05)
    x = 2 * np.pi * q / period
    f = sum(a_sin[i] * np.sin((i + 1) * x) + a_cos[i] * np.cos((i + 1) * x) for i in range(2))
    assert np.abs((e - e0) - f).max() < 0.05 * np.ptp(f)
    cubic = HiddenEffects(viscous_nonlinear=np.array([0, 0, 30.0]), viscous_exponent=np.array([2, 2, 3.0]))
    _, e3 = sweep(cubic, 0.15)
    _, e30 = sweep(HiddenEffects(), 0.15)
    assert np.median(e3 - e30) == pytest.approx(30.0 * 0.15 ** 3, rel=0.05)


def test_per_joint_effort_delay():
    w = SimWorld([ArmSpec("A", effects=HiddenEffects(time_delay=np.array([0.0, 0.02, 0.0])),
                          noise=SensorNoise.off())])
    w.servo_jf("A", np.zeros(3))
    w.advance(0.05)
    w.servo_jf("A", np.array([0.3, 0.3, 0.3]))
    w.advance(0.01)
    e = w.measured_js("A")[2]
    assert e[0] == pytest.approx(0.3) and e[2] == pytest.approx(0.3) and e[1] == 0.0
    w.advance(0.011)
    assert w.measured_js("A")[2][1] == pytest.approx(0.3)


def test_configured_plant_model_builds_the_arm(tmp_path):
    entries = [{"name": "spring", "joint": 3, "params": {"k": 40.0, "q0": 0.1}},
               {"name": "payload", "joint": 3, "params": {"mass": 0.2}, "applied_to": "standard_parameters"}]
    heavier = PSMParameters().with_payload(0.3)
    path = save_model(tmp_path / "model.json", standard=heavier.standard_vector(), names=PSMDynamics.param_names(),
                      slope=400.0, gravity=[0, 0, -9.81], extra={"effects": entries})
    toml = tmp_path / "rig.toml"
    toml.write_text('[arms.PSM1]\nplant_model = "model.json"\n[arms.PSM2]\nbase_xyz = [0.2, 0, 0]\n')
    cfg = config.load(toml)
    assert cfg.arms["PSM1"]["plant_model"] == str(path.resolve())   # relative to the file's folder
    w = world_from_config(cfg, with_object=False)
    a = w.arms["PSM1"]
    np.testing.assert_allclose(a.params.standard_vector(), heavier.standard_vector())
    assert a.spec.effects.spring[2] == 40.0 and a.spec.effects.spring_rest[2] == 0.1
    assert w.arms["PSM2"].params.bodies["tool"].mass == PSMParameters().bodies["tool"].mass
    # `rig sim --plant-model` sets it on every simulated arm and drops their hidden effects.
    hidden = config.parse({"effects": {"PSM2": {"spring": [0, 0, 5.0]}}}, "built-in")
    both = config.with_plant_model(hidden, path)
    assert all(a["plant_model"] == str(path.resolve()) for a in both.arms.values()) and not both.effects


def test_plant_model_errors_name_the_problem(tmp_path):
    good = save_model(tmp_path / "m.json", standard=NOMINAL.standard_vector(), names=PSMDynamics.param_names(),
                      slope=400.0, gravity=[0, 0, -9.81], extra={"effects": []})
    with pytest.raises(config.ConfigError, match="effects.PSM1: the arm's plant is arms.PSM1.plant_model"):
        config.parse({"arms": {"PSM1": {"plant_model": str(good)}}, "effects": {"PSM1": {"spring": [1, 0, 0]}}}, "t")
    with pytest.raises(config.ConfigError, match="only a simulated arm"):
        config.parse({"arms": {"PSM1": {"driver": "ros", "plant_model": str(good)}}}, "t")
    with pytest.raises(config.ConfigError, match="arms.PSM1.plant_model: .*no such model file"):
        config.parse({"arms": {"PSM1": {"plant_model": str(tmp_path / "missing.json")}}}, "t")
    two = [{"name": "position_friction", "joint": 3, "params": {"period": 0.1, "a_sin": [0.1], "a_cos": [0.0]}},
           {"name": "position_friction", "joint": 3, "params": {"period": 0.05, "a_sin": [0.1], "a_cos": [0.0]}}]
    with pytest.raises(ModelFileError, match=r"effects\[1\] \(position_friction@3\): cannot be simulated: "
                                             "a second friction profile"):
        _model_file(tmp_path / "two.json", two).plant()
    doc = json.loads(good.read_text())
    doc["effects"] = [{"name": "magnetism", "joint": 1, "params": {}}]
    good.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=r"effects\[0\]: not a catalogue effect \(name 'magnetism'"):
        load_model(good).plant()
    with pytest.raises(ModelFileError, match="needs a Dahl level Fd > 0"):
        _model_file(tmp_path / "h.json", [{"name": "hysteresis", "joint": 2,
                                           "params": {"Fd": 0.1, "travel": 0.0}}]).plant()


def test_rig_sim_plant_model_option_refuses_a_bad_file(tmp_path):
    from click.testing import CliRunner

    from rig.cli import main

    res = CliRunner().invoke(main, ["sim", "--plant-model", str(tmp_path / "none.json"), "--duration", "0.1"])
    assert res.exit_code == 2
    assert f"Invalid value for --plant-model: {tmp_path / 'none.json'}: no such model file" in res.output


def test_an_entry_without_its_parameters_is_named(tmp_path):
    m = _model_file(tmp_path / "m.json", [{"name": "spring", "joint": 2, "params": {"q0": 0.1}}])
    with pytest.raises(ModelFileError, match=r"effects\[0\] \(spring@2\): cannot be simulated: parameter 'k' missing"):
        m.plant()
