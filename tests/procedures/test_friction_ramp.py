"""`rig friction-ramp` on the simulated rig with joint-3 stiction, and the friction fits."""

import json

import numpy as np
import pytest

from rig import config
from rig.commands.parameters import resolve

STICTION = 1.0  # N, the simulated breakaway level of joint 3


def _run(tmp_path, extra_toml="", values=None):
    from procedures import friction_ramp

    (tmp_path / "rig.toml").write_text(f"[effects.PSM1]\nstiction = [0.0, 0.0, {STICTION}]\n{extra_toml}")
    cfg = config.load(tmp_path / "rig.toml")
    return friction_ramp.run(cfg, resolve(friction_ramp.PARAMETERS, values or {}), progress=False)


def _expected(world_params, effects_offset, comp_dyn, q3):
    """Breakaway forces beyond the compensation that the simulated joint 3 must show.

    The joint sticks while |tau_cmd - L| <= Fs, with the true static load L = g3(q) + Fo3
    + hidden constant load, and tau_cmd = C + ramp with the compensation C = g3_model(q) +
    Fo3_model. So it breaks away at ramp = +Fs + (L - C) and at ramp = -Fs + (L - C).
    """
    from rig.model.psm_dynamics import PSMDynamics

    q = np.array([0.0, 0.0, q3])
    true = PSMDynamics(world_params)
    load = true.gravity_torque(q)[2] + true.Fo[2] + effects_offset
    comp = comp_dyn.gravity_torque(q)[2] + comp_dyn.Fo[2]
    return STICTION + (load - comp), -STICTION + (load - comp)


def test_breakaway_with_a_compensation_error(tmp_path):
    """A hidden constant load of 0.3 N on joint 3 the nominal model does not know: Fs+ and
    Fs- shift by it, each within 10 % of Fs of what the physics says, and their
    half-difference is Fs itself."""
    from rig.model.psm_dynamics import PSMDynamics, PSMParameters

    r = _run(tmp_path, "torque_offset = [0.0, 0.0, 0.3]\n", {"speeds": "0.005,0.02,0.08", "plots": False})
    assert r["status"] == "completed"
    assert r["compensation"]["kind"] == "nominal"
    exp_pos, exp_neg = _expected(PSMParameters(), 0.3, PSMDynamics(), r["q_ref"][2])
    assert abs(exp_pos - (STICTION + 0.3)) < 1e-9 and abs(exp_neg - (-STICTION + 0.3)) < 1e-9
    assert abs(r["Fs_pos"] - exp_pos) <= 0.1 * STICTION, (r["Fs_pos"], exp_pos)
    assert abs(r["Fs_neg"] - exp_neg) <= 0.1 * STICTION, (r["Fs_neg"], exp_neg)
    assert abs(r["Fs_symmetric"] - STICTION) <= 0.1 * STICTION
    assert abs(r["compensation_bias"] - 0.3) <= 0.05
    # the procedure's own statement of the truth agrees with the test's
    assert abs(r["truth"]["expected_Fs_pos"] - exp_pos) < 1e-6


def test_friction_ramp_full_and_model_file(tmp_path):
    """Default sweeps: Fs+/Fs- within 10 %, Stribeck fit near the simulated friction law,
    a friction-only model file (no identify run yet) that latest_model() finds."""
    from rig.model.model_file import load_model
    from rig.runs.model_results import latest_model
    from rig.model.psm_dynamics import DriveParameters

    r = _run(tmp_path)
    assert abs(r["Fs_pos"] - r["truth"]["expected_Fs_pos"]) <= 0.1 * STICTION
    assert abs(r["Fs_neg"] - r["truth"]["expected_Fs_neg"]) <= 0.1 * STICTION
    st = r["fits"]["stribeck"]
    drive = DriveParameters()
    assert st["success"]
    assert abs(st["Fc"] - drive.Fc[2]) < 0.1 * drive.Fc[2]
    assert abs(st["Fo"] - drive.Fo[2]) < 0.05
    assert 0.7 * STICTION < st["Fs"] < 1.1 * STICTION
    assert st["rms"] < r["fits"]["viscous_coulomb"]["rms"]
    m = load_model(r["model"])
    assert m.kind == "friction-only" and m.stick_slip().fs_pos == r["Fs_pos"]
    with pytest.raises(ValueError, match="friction-only"):
        m.dynamics()
    assert latest_model().path == m.path
    assert (tmp_path / "logs").exists()
    assert len(list((tmp_path / "logs").glob("*-friction-ramp/figure_5_*.png"))) == 2


def test_breakaway_detection_onset():
    from calibration.friction_fit import breakaway

    rng = np.random.default_rng(0)
    v = rng.normal(0, 3e-4, 400)
    v[250:] += np.linspace(0, 0.02, 150)  # starts sliding at sample 250
    v[100] = 0.01  # one noisy spike is no breakaway
    k = breakaway(np.arange(400.0), v, 0.005)
    assert 245 <= k <= 265
    assert breakaway(np.arange(400.0), -v, 0.005) is None
    assert breakaway(np.arange(400.0), -v, 0.005, direction=-1) == k


def test_stribeck_fit_recovers_parameters():
    from calibration.friction_fit import fit_stribeck, fit_viscous_coulomb, stribeck_curve

    p = [0.15, 0.77, 0.53, 1.0, 0.01]
    v = np.concatenate([-np.geomspace(0.001, 0.1, 12), np.geomspace(0.001, 0.1, 12)])
    f = stribeck_curve(p, v) + np.random.default_rng(1).normal(0, 0.002, v.size)
    st = fit_stribeck(v, f)
    assert st["success"]
    for name, true in zip(("Fo", "Fv", "Fc", "Fs", "vs"), p):
        assert abs(st[name] - true) < 0.05 * abs(true) + 0.01, (name, st[name], true)
    vc = fit_viscous_coulomb(v, f)
    assert vc["rms"] > 5 * st["rms"]


def test_stribeck_fit_reports_no_excess_where_friction_dips_below_coulomb_at_low_speed():
    """Friction a little below Fc + Fv v at low speed (0.011 N, as the simulated plant's
    joint 3 shows on the default sweep) is no static level above Coulomb: the fit keeps
    Fs >= Fc, and calls the excess unresolved. Where the excess leaves no trace in the
    swept speeds, it is reported as none (Fs = Fc) with no uncertainty, not as a number."""
    from calibration.friction_fit import fit_stribeck, stribeck_curve

    speeds = np.array([0.0025, 0.005, 0.01, 0.02, 0.04, 0.08])   # the procedure's default sweep
    v = np.repeat(np.concatenate([-speeds, speeds]), 3)
    dip = 0.15 + 0.6 * v + np.sign(v) * (0.536 - 0.011 * np.exp(-(np.abs(v) / 0.027) ** 2))
    flat = 0.15 + 0.6 * v + 0.536 * np.sign(v)
    for seed, f in enumerate((dip, flat)):
        f = f + np.random.default_rng(seed).normal(0, 0.001, v.size)
        st = fit_stribeck(v, f)
        assert not st["success"] and not st["stribeck_resolved"]
        assert st["Fs"] == st["Fc"] and abs(st["Fc"] - 0.536) < 0.015
        assert st["std"]["dFs"] is None and st["std"]["Fc"] < 0.002
        # reporting no excess does not change the fitted curve on the data
        p = [st[k] for k in ("Fo", "Fv", "Fc", "Fs", "vs")]
        assert np.sqrt(np.mean((stribeck_curve(p, v) - f) ** 2)) == pytest.approx(st["rms"], rel=1e-6)


def test_model_file_round_trip_and_errors(tmp_path):
    from rig.model.model_file import ModelFileError, StickSlip, load_model, save_model, with_stick_slip
    from rig.runs.model_results import latest_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    pi = PSMDynamics().standard_params() * 1.1
    g = np.array([0.5, -0.2, -9.79])
    path = save_model(tmp_path / "model.json", standard=pi, names=standard_parameter_names(), slope=50.0,
                      gravity=g, base_values=[1.0, 2.0], base_expressions=["a", "b"], base_independent=[0, 1],
                      validation={"relative_error": {"sdp": [0.01, 0.02, 0.03]}},
                      provenance_info={"data_source": "test"})
    m = load_model(path)
    assert np.array_equal(m.standard, pi) and m.slope == 50.0 and np.array_equal(m.gravity, g)
    dyn = m.dynamics()
    assert np.allclose(dyn.standard_params(), pi, rtol=1e-9, atol=1e-12)
    assert dyn.slope == 50.0 and np.allclose(dyn.gravity, g)
    assert m.friction["joints"][2]["Fc"] == pi[78]
    assert m.stick_slip() is None
    stick = StickSlip(3, 1.02, -0.98, {"viscous_coulomb": {"Fo": 0.1, "Fv": 0.7, "Fc": 0.5}},
                      {"velocity": 0.005, "position": 0.0003})
    before = path.read_bytes()
    m2 = with_stick_slip(tmp_path / "ramp" / "model.json", m, stick, {"data_source": "ramp test"})
    assert path.read_bytes() == before  # the earlier model's file is its run's record
    assert m2.provenance["rigid_body_from"] == str(path)
    assert np.array_equal(m2.standard, pi)
    assert m2.stick_slip().fs_pos == 1.02
    assert m2.stick_slip().compensation(0.0, 0.001) == 1.02
    assert m2.stick_slip().compensation(0.0, -0.001) == -0.98
    assert m2.stick_slip().compensation(0.0, 0.0) == 0.0
    assert abs(m2.stick_slip().compensation(0.1, 0.0) - (0.1 + 0.07 + 0.5)) < 1e-12
    # errors that name the file and the problem
    with pytest.raises(ModelFileError, match="no such model file"):
        load_model(tmp_path / "missing.json")
    bad = tmp_path / "corrupt.json"
    bad.write_text(path.read_text()[:200])
    with pytest.raises(ModelFileError, match="corrupt"):
        load_model(bad)
    doc = json.loads(path.read_text())
    doc["schema_version"] = 99
    (tmp_path / "future.json").write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="schema version 99"):
        load_model(tmp_path / "future.json")
    doc["schema_version"] = 1
    doc["standard_parameters"]["values"] = doc["standard_parameters"]["values"][:80]
    (tmp_path / "short.json").write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="expected 82"):
        load_model(tmp_path / "short.json")
    assert latest_model() is None  # no identify run in this test's logs


def test_model_file_stribeck_term(tmp_path):
    """The identified Stribeck excess travels through the model file into the dynamics; a
    file without it (the earlier format) still loads, with no excess; a malformed one is a
    clear error."""
    from rig.model.model_file import ModelFileError, load_model, save_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    pi = PSMDynamics().standard_params()
    common = dict(standard=pi, names=standard_parameter_names(), slope=400.0, gravity=[0.0, 0.0, -9.81])
    plain = load_model(save_model(tmp_path / "plain.json", **common))
    assert plain.stribeck is None and np.all(plain.dynamics().Fst == 0)
    st = {"Fst": [0.0, 0.0, 0.45], "vs": [0.01, 0.01, 0.008]}
    m = load_model(save_model(tmp_path / "stribeck.json", stribeck=st, **common))
    dyn, ref = m.dynamics(), plain.dynamics()
    for v in (0.002, 0.008, -0.004, 0.05):
        dq = np.array([0.0, 0.0, v])
        excess = 0.45 * np.exp(-(v / 0.008) ** 2) * np.tanh(200.0 * v)
        assert dyn.friction(dq)[2] - ref.friction(dq)[2] == pytest.approx(excess, abs=1e-12)
        assert (dyn.stribeck_columns(dq[None], st["vs"]) @ np.array(st["Fst"]))[2] == pytest.approx(excess, abs=1e-12)
    assert np.allclose(dyn.inverse_dynamics(np.array([0.1, 0.2, 0.1]), np.array([0.0, 0.0, 0.005]), np.zeros(3))
                       - ref.inverse_dynamics(np.array([0.1, 0.2, 0.1]), np.array([0.0, 0.0, 0.005]), np.zeros(3)),
                       [0.0, 0.0, 0.45 * np.exp(-(0.005 / 0.008) ** 2) * np.tanh(1.0)])
    doc = json.loads((tmp_path / "stribeck.json").read_text())
    doc["friction"]["stribeck"]["vs"] = [0.01, 0.0, 0.01]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="bad.json: malformed friction.stribeck"):
        load_model(tmp_path / "bad.json").dynamics()


def test_latest_model_merges_a_newer_friction_ramp_without_rewriting_the_identify_run(tmp_path):
    """The identify run's model.json is its record: a later friction-ramp result is merged
    into the model latest_model() returns, and the earlier file stays byte for byte."""
    from rig.model.model_file import STICK_SLIP_FILENAME, StickSlip, save_model
    from rig.runs.model_results import latest_model
    from rig.runs.paths import runs_root
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    root = runs_root()
    ident = root / "20261121T070000Z-identify"
    ramp = root / "20261121T080000Z-friction-ramp"
    for d in (ident, ramp):
        d.mkdir(parents=True)
        (d / "result.json").write_text(json.dumps({"status": "completed"}))
    path = save_model(ident / "model.json", standard=PSMDynamics().standard_params(), names=standard_parameter_names(),
                      slope=400.0, gravity=np.array([0.0, 0.0, -9.81]), provenance_info={"data_source": "test"})
    before = path.read_bytes()
    stick = StickSlip(3, 1.02, -0.98, {"viscous_coulomb": {"Fo": 0.1, "Fv": 0.7, "Fc": 0.5}},
                      {"velocity": 0.005, "position": 0.0003}, {"run_dir": str(ramp)})
    (ramp / STICK_SLIP_FILENAME).write_text(json.dumps(stick.to_dict()))
    m = latest_model()
    assert m.path == path
    assert m.stick_slip().fs_pos == 1.02 and m.stick_slip().fs_neg == -0.98
    assert path.read_bytes() == before


def test_a_stribeck_fit_that_did_not_converge_is_reported_in_plain_words_and_not_compensated_with(tmp_path,
                                                                                                   monkeypatch):
    """The run did its job (breakaway forces, the viscous + Coulomb fit): an unresolved
    Stribeck curve is said so without a shouted 'NOT resolved' on a completed run, and the
    model file compensates with the viscous + Coulomb fit, not the unconverged curve."""
    import calibration.friction_fit as ff
    from procedures.friction_ramp import report
    from rig.model.model_file import load_model

    real = ff.fit_stribeck

    def unconverged(*args, **kwargs):
        return {**real(*args, **kwargs), "success": False}

    monkeypatch.setattr(ff, "fit_stribeck", unconverged)
    r = _run(tmp_path, values={"speeds": "0.005,0.02,0.08", "plots": False})
    assert r["status"] == "completed"
    assert "stribeck" not in r["stick_slip"]["fits"] and "viscous_coulomb" in r["stick_slip"]["fits"]
    st = load_model(r["model"]).stick_slip()
    assert "stribeck" not in st.fits
    text = report(r)
    assert "NOT resolved" not in text and "Stribeck curve: not determined by the swept speeds" in text, text
    # where the model went: its own file, and what it holds
    assert f"model file written: {r['model']} (friction terms only" in text, text
    assert "written to the" not in text
