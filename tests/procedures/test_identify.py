"""`rig identify`: offline on the real dVRK CSV, bad inputs, and live on the simulated rig."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig import config
from rig.commands.parameters import resolve

# The shared data sit beside the repository (../shared); a clone elsewhere on the lab machine
# finds them at /work/shared.
REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "wpi-psm" / "one_results.csv"
if not REAL.exists():
    REAL = Path("/work/shared/data/wpi-psm/one_results.csv")


ROOT = Path(__file__).resolve().parents[2]


def rig_cli(*args, cwd):
    """Run `rig ...` in a subprocess; returns (exit code, stdout, stderr). The subprocess
    imports this checkout's packages (not an installed copy elsewhere): it runs in ``cwd``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    p = subprocess.run([sys.executable, "-m", "rig.cli", *args], cwd=cwd, capture_output=True, text=True,
                       env=env, timeout=120)
    return p.returncode, p.stdout, p.stderr


@pytest.mark.skipif(not REAL.exists(), reason="shared/data/wpi-psm/one_results.csv not available")
def test_offline_real_csv_json(tmp_path):
    from calibration.datasets import load_csv, processed
    from rig.model.model_file import load_model
    from rig.runs.model_results import latest_model

    code, out, err = rig_cli("identify", "--csv", str(REAL), "--json", cwd=tmp_path)
    assert code == 0, err
    doc = json.loads(out)
    assert Path(doc["model"]).exists()
    for m in ("ols", "wls", "sdp"):
        e = np.array(doc["validation"][m])
        assert e.shape == (3,) and np.all(np.isfinite(e)) and np.all(e < 0.25), (m, e)
    assert doc["checks"]["sdp"] is True
    assert doc["gravity"]["source"] == "estimated"
    assert abs(np.linalg.norm(doc["gravity"]["vector"]) - 9.81) < 1e-6
    # The model file is found by later runs and predicts what the SDP fit predicted.
    model = latest_model()
    assert model is not None and model.path == Path(doc["model"])
    assert model.path == load_model(doc["model"]).path
    dyn = model.dynamics()
    data = processed(load_csv(REAL, 200.0, 3))
    k = np.linspace(0, data.n_samples - 1, 40).astype(int)
    pred = np.array([dyn.inverse_dynamics(data.q[i], data.dq[i], data.ddq[i]) for i in k])
    W = dyn.regressor_batch(data.q[k], data.dq[k], data.ddq[k])
    beta = np.array(model.document["base_parameters"]["values"])
    cols = np.array(model.document["base_parameters"]["independent"])
    fit = W[:, cols] @ beta
    st = model.stribeck  # joint 3's identified Stribeck excess (>= 0), part of the SDP fit
    assert st is not None and st["Fst"][2] >= 0 and np.all(st["Fst"][:2] == 0)
    fit = fit + dyn.stribeck_columns(data.dq[k], st["vs"]) @ st["Fst"]
    assert np.allclose(pred, fit.reshape(-1, 3), rtol=1e-6, atol=1e-6)
    assert len(list(Path(doc["run_dir"]).glob("figure_5_*.png"))) == 2


def _write(path, rows):
    path.write_text("\n".join(",".join(f"{x:.9g}" for x in r) for r in rows) + "\n")
    return path


def _synthetic_rows(n=1200, rate=200.0, seed=0):
    """Exciting 3-joint data in the WPI layout (q | dq | tau), torques from the nominal model."""
    from calibration.excitation import FourierTrajectory, rest_basis
    from rig.model.psm_dynamics import PSMDynamics

    rng = np.random.default_rng(seed)
    Z = rest_basis(0.2, n / rate)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T * np.array([[0.5], [0.4], [0.05]])
    tr = FourierTrajectory(0.2, c[:, :5], c[:, 5:], np.array([0.0, 0.0, 0.12]), n / rate)
    q, dq, ddq = tr.sample(np.arange(n) / rate)
    dyn = PSMDynamics()
    tau = np.array([dyn.inverse_dynamics(a, b, d) for a, b, d in zip(q, dq, ddq)])
    return np.hstack([q, dq, tau])


@pytest.mark.parametrize("case", ["columns", "nan", "time", "not_exciting", "joint_still", "short"])
def test_bad_csv_clear_error(tmp_path, case):
    rows = _synthetic_rows()
    extra = []
    if case == "short":  # 0.5 s: the filter's settling alone trims more at each end
        f = _write(tmp_path / "bad.csv", rows[:100])
        expect = "100 rows (0.5 s at 200 Hz) are too few: identification needs at least 917 (4.6 s)"
    elif case == "columns":
        f = _write(tmp_path / "bad.csv", rows[:, :-1])  # 8 columns
        expect = "not a multiple of 3"
    elif case == "nan":
        rows[100, 4] = np.nan
        f = _write(tmp_path / "bad.csv", rows)
        expect = "line 101"
    elif case == "time":
        t = np.arange(len(rows)) / 200.0
        t[500] = t[498]
        f = _write(tmp_path / "bad.csv", np.column_stack([t, rows]))
        extra = ["--time-column"]
        expect = "time does not increase"
    else:
        # Constant velocities: no acceleration and one Coulomb sign, so the rotor inertias
        # and Coulomb levels cannot be told from the offsets.
        n = len(rows)
        t = np.arange(n) / 200.0
        q = np.column_stack([0.1 * t, 0.05 * t, 0.12 + 0.01 * t])
        dq = np.tile([0.1, 0.05, 0.01], (n, 1))
        tau = np.random.default_rng(1).normal(size=(n, 3))
        f = _write(tmp_path / "bad.csv", np.hstack([q, dq, tau]))
        expect = "does not excite"
        if case == "joint_still":  # joint 3 creeps below the 7.5.1 deadband the whole time
            q[:, 2], dq[:, 2] = 0.12 + 0.001 * t, 0.001
            tau = _synthetic_rows()[:, 6:]
            f = _write(tmp_path / "bad.csv", np.hstack([q, dq, tau]))
            expect = "joint 3 moves faster than its deadband"
    code, out, err = rig_cli("identify", "--csv", str(f), *extra, "--json", cwd=tmp_path)
    assert code != 0
    assert expect in err, err
    assert str(f) in err
    assert "Traceback" not in err


def test_timed_csv_is_resampled(tmp_path):
    from calibration.datasets import load_timed_csv

    rows = _synthetic_rows(n=400)
    t = np.arange(400) / 200.0 + np.random.default_rng(2).uniform(-1e-4, 1e-4, 400)
    f = _write(tmp_path / "timed.csv", np.column_stack([t, rows]))
    data = load_timed_csv(f, 200.0, 3)
    assert np.allclose(np.diff(data.t), 1 / 200.0)
    assert np.allclose(data.q[:, 0], np.interp(data.t, t, rows[:, 0]))


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    """The excitation design cache in the test's folder, not the user's."""
    monkeypatch.setenv("RIG_CACHE", str(tmp_path / "cache"))


def test_excitation_design_is_cached_where_every_later_run_finds_it(tmp_path, monkeypatch):
    from procedures.identify import PARAMETERS
    from procedures.identify_trajectories import design_excitation, plant_of

    cfg = _empty_config(tmp_path)
    p = resolve(PARAMETERS, {"duration": 6.0, "starts": 1, "iterations": 2})
    g = np.array([0.0, 0.0, -9.81])
    plant = plant_of(cfg, "PSM1")
    assert plant.rate == cfg.rig["rate"]
    first = design_excitation(p, g, plant, processes=1)
    assert first["path"].startswith(str(tmp_path / "cache")) and "logs" not in first["path"]
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "another-logs-folder"))
    second = design_excitation(p, g, plant, processes=1)
    assert not first["cached"] and second["cached"] and first["key"] == second["key"]
    assert np.allclose(first["excitation"].a, second["excitation"].a)
    # another setting is another design (every input's part in the key: tests/calibration/test_excitation_design.py)
    from calibration.excitation_design import design_key
    from procedures.identify_trajectories import design_settings
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    other = resolve(PARAMETERS, {"duration": 6.0, "starts": 1, "iterations": 2, "frequency": 0.2})
    assert design_key(design_settings(other), g, plant, Q_MIN, Q_MAX, DQ_MAX)[1] != first["key"]


def _empty_config(tmp_path):
    (tmp_path / "rig.toml").write_text("")
    return config.load(tmp_path / "rig.toml")


def test_stream_aborts_before_the_limit_when_the_arm_tracks_worse_than_its_margin(tmp_path):
    """A trajectory 2 mm above joint 3's lower limit with a margin that claims the arm
    tracks within 0.5 mm: the simulated arm (whose true overshoot there is several mm, as
    its plant says) is stopped and held before the limit, not at the console's fault."""
    from calibration.excitation import FourierTrajectory, rest_basis
    from calibration.excitation_design import Margin, Plant, tracking_error
    from procedures.identify_trajectories import reach_start, stream_trajectory
    from rig.devices.factory import open_rig
    from rig.model.psm_kinematics import JointLimits
    from rig.runs.run import AbortRun, Run

    cfg = _empty_config(tmp_path)
    rng = np.random.default_rng(3)
    Z = rest_basis(0.5, 4.0)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T
    raw = FourierTrajectory(0.5, c[:, :5], c[:, 5:], np.zeros(3), 4.0)
    q, dq, _ = raw.sample(raw.times(cfg.rig["rate"]))
    s = np.array([1.2, 1.2, 0.3]) / np.abs(dq).max(axis=0)
    q = q * s
    traj = FourierTrajectory(0.5, raw.a * s[:, None], raw.b * s[:, None],
                             np.array([0.0, 0.0, 0.002 - q[:, 2].min()]), 4.0)
    dev = open_rig(cfg, ["PSM1"], seed=0, uses=())
    world = dev.world
    truth = tracking_error(traj, Plant(world.arms["PSM1"].spec, cfg.rig["rate"], np.asarray(cfg.rig["gravity"])))
    assert truth["position"][2] > 0.002  # unchecked, joint 3 would pass its limit 0
    claimed = Margin(np.array([0.05, 0.05, 0.002]), np.array([0.1, 0.1, 0.05]), np.zeros(3), np.zeros(3),
                     cfg.rig["rate"], np.array([0.05, 0.05, 0.05]))
    lowest = []
    world_q3 = []
    dev.clock.add_listener(lambda t: world_q3.append(world.qm[2]))
    try:
        dev.operator.detach_object()
        with pytest.raises(AbortRun) as err:
            with Run("identify", parameters={}, config=None, steps=["stream"], progress=False) as run:
                arm = run.claim(dev.arms["PSM1"])
                reach_start(arm, traj.sample([0.0])[0][0], "excitation", lambda text: None)
                with run.step("stream", total=1) as st:
                    stream_trajectory(run, arm, dev.clock, traj, "excitation", st, JointLimits(), claimed)
        line = err.value.reason
        assert "joint 3 at" in line and "from its limit 0 m" in line and "\n" not in line
        lowest.append(float(line.split("joint 3 at ")[1].split(" m")[0]))
        assert 0.0 < lowest[0] <= 0.25 * 0.002  # within the last quarter of the margin, above the limit
        dev.clock.sleep(0.5)  # the run held the arm: it stops short of the console's fault band
        from drivers.arm.fake_arm_state import LIMIT_MARGIN
        assert min(world_q3) > -LIMIT_MARGIN[2]
        assert dev.arms["PSM1"].measured_js().position[2] > -LIMIT_MARGIN[2]
    finally:
        dev.close()


STICTION_RIG = "[effects.PSM1]\nstiction = [0.0, 0.0, 1.0]\n"


def _live(tmp_path, values):
    from procedures import identify

    (tmp_path / "rig.toml").write_text(STICTION_RIG)
    cfg = config.load(tmp_path / "rig.toml")
    assert cfg.arms["PSM1"]["sensor_noise"] is True
    return identify.run(cfg, resolve(identify.PARAMETERS, values), progress=False)


def test_live_simulated_short(tmp_path):
    """A 10 s excitation on the simulated rig with sensor noise and joint-3 stiction:
    the SDP model must predict the true parameters' torques within 5 % per joint, and the
    measured ones where the joints move."""
    from procedures import friction_ramp
    from rig.runs.model_results import latest_model
    from rig.model.psm_dynamics import PSMDynamics

    # friction-ramp first, then identify: the identified model file carries the ramp's
    # stick-slip terms (either order gives the same model)
    (tmp_path / "rig.toml").write_text(STICTION_RIG)
    ramp = friction_ramp.run(config.load(tmp_path / "rig.toml"), resolve(friction_ramp.PARAMETERS, {"plots": False}),
                             progress=False)
    assert ramp["status"] == "completed" and ramp["provenance"]["arms"][0]["name"] == "PSM1"
    r = _live(tmp_path, {"duration": 10.0, "starts": 1, "iterations": 5, "plots": False})
    assert r["status"] == "completed"
    written = json.loads(Path(r["model"]).read_text())
    assert written["stick_slip"]["Fs_pos"] == ramp["Fs_pos"]
    assert Path(written["stick_slip"]["provenance"]["run_dir"]).name == Path(ramp["run_dir"]).name
    assert r["stick_slip_from"] == f"stick-slip terms of joint 3 taken from friction-ramp run {Path(ramp['run_dir']).name}"
    truth = np.array(r["truth"]["sdp_vs_true_relative_error"])
    assert np.all(truth <= 0.05), truth
    assert r["checks"]["sdp"] is True
    assert np.all(np.array(r["validation"]["sdp"][:2]) < 0.05)
    assert np.all(np.array(r["validation_moving"]["sdp"]) <= 0.05), r["validation_moving"]
    # Joint 3's identified Stribeck excess is the simulator's stiction above Coulomb (within
    # the bias of the smooth sign tanh(a dq/2) against the simulator's exact one), and with it
    # the model is closer to the simulator's sliding friction than the plain eq. 4.16 law.
    st = r["truth"]["stribeck"]
    assert 0.5 * st["true_Fst"][2] < st["identified_Fst"][2] < 1.5 * st["true_Fst"][2], st
    assert r["truth"]["sdp_vs_true_relative_error"][2] < r["truth"]["sdp_vs_nominal_law_relative_error"][2]
    # The model file: found, and its dynamics close to the simulator's true parameters.
    model = latest_model()
    dyn, true = model.dynamics(), PSMDynamics()
    assert np.allclose(model.gravity, [0.0, 0.0, -9.81])
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = np.array([rng.uniform(-1, 1), rng.uniform(-0.6, 0.6), rng.uniform(0.05, 0.2)])
        g_err = dyn.gravity_torque(q) - true.gravity_torque(q)
        assert np.all(np.abs(g_err) < np.array([0.1, 0.1, 0.2])), g_err


@pytest.mark.slow
def test_live_simulated_full_target(tmp_path):
    """The issue's target with the default 30 s trajectories (the design takes ~1 min): SDP
    within 5 % of the true parameters' efforts and of the measured efforts where the joints
    move (predictions low-passed like the measurements), every joint."""
    r = _live(tmp_path, {})
    truth = np.array(r["truth"]["sdp_vs_true_relative_error"])
    assert np.all(truth <= 0.05), truth
    moving = np.array(r["validation_moving"]["sdp"])
    assert np.all(moving <= 0.05), moving
    # Joint 3's stick-slip steps are what parallel filtering brings into the comparison.
    unfiltered = np.array(r["validation_moving_unfiltered"]["sdp"])
    assert unfiltered[2] > moving[2], (unfiltered, moving)
    assert r["table_5_1"]["optimisation_condition"] < 300


def test_position_friction_of_joint_3_is_identified_where_it_is_and_left_out_where_it_is_not(tmp_path):
    """`--position-friction auto`: on efforts with a joint-3 Coulomb ripple of 0.3 N and a
    5.4 cm period (a catalogue period), the profile is chosen by cross-validation over
    blocks in time, lands in the model file as an effect, and the held-out joint-3 error
    falls; on the same motion without it, no profile beats the plain model and none is
    written."""
    from calibration.effects import CATALOGUE
    from rig.model.model_file import load_model

    period = CATALOGUE["position_friction"].grid(3)[4]
    rows = _synthetic_rows(n=3000, seed=2)
    rng = np.random.default_rng(5)
    rows[:, 6:] += rng.normal(scale=[0.02, 0.02, 0.03], size=(len(rows), 3))  # effort noise, N m and N
    plain = _write(tmp_path / "plain.csv", rows)
    ripple = rows.copy()
    q3, dq3 = rows[:, 2], rows[:, 5]
    ripple[:, 8] += np.tanh(0.5 * 400.0 * dq3) * 0.3 * np.sin(2 * np.pi * q3 / period + 0.4)
    ripple = _write(tmp_path / "ripple.csv", ripple)
    out = {}
    for name, f in (("plain", plain), ("ripple", ripple)):
        for mode in ("off", "auto"):
            code, stdout, err = rig_cli("identify", "--csv", str(f), "--position-friction", mode, "--friction-slope",
                                        "400", "--gravity", "0,0,-9.81", "--no-plots", "--json", cwd=tmp_path)
            assert code == 0, err
            out[name, mode] = json.loads(stdout.strip().splitlines()[-1])
    chosen = out["ripple", "auto"]["selection"]["position_friction"][0]["chosen"]
    assert chosen is not None and chosen["period"] == pytest.approx(period)
    effect = out["ripple", "auto"]["position_friction"]
    assert effect["joint"] == 3 and 0.2 < effect["params"]["amplitude"] < 0.4, effect["params"]
    assert load_model(out["ripple", "auto"]["model"]).effects[0]["name"] == "position_friction"
    j3 = {k: v["validation"]["sdp"][2] for k, v in out.items()}
    assert j3["ripple", "auto"] < 0.7 * j3["ripple", "off"], j3
    # without a ripple in the data: nothing chosen, nothing written, nothing lost
    assert out["plain", "auto"]["selection"]["position_friction"][0]["chosen"] is None
    assert "position_friction" not in out["plain", "auto"]
    assert not load_model(out["plain", "auto"]["model"]).effects
    assert j3["plain", "auto"] == pytest.approx(j3["plain", "off"], rel=1e-6)


def test_effects_from_a_model_file_are_identified_with_the_rigid_body(tmp_path):
    """`--effects-from M`: M's spring on the insertion joint is fitted with the rigid body at
    its stated law. On a plant with that spring the plain fit tilts the gravity (the spring
    looks like one) and the spring's fit restores it, its stiffness the plant's within 3 %;
    an offset in M is left out and named (Fo is the model's own term)."""
    from calibration.hidden_effects import HiddenCase, draw_case_parameters
    from tests.sim_cache import recorded
    from calibration.identification import make_model
    from rig.model.model_file import load_model, save_model

    case = HiddenCase((("spring", 3),), 1)
    rec, _ = recorded(case)
    data = _write(tmp_path / "spring.csv", np.hstack([rec.q, rec.dq, rec.tau]))
    model = make_model([0.0, 0.0, -9.81], 400.0)
    source = save_model(tmp_path / "effects.json", standard=np.zeros(82), names=list(model.param_names()),
                        slope=400.0, gravity=[0.0, 0.0, -9.81],
                        extra={"effects": [{"name": "spring", "joint": 3, "params": {"k": 1.0, "q0": 0.1}},
                                           {"name": "torque_offset", "joint": 2, "params": {"offset": 0.1}}]})
    out = {}
    for label, extra in (("plain", []), ("spring", ["--effects-from", str(source)])):
        code, stdout, err = rig_cli("identify", "--csv", str(data), *extra, "--no-plots", "--json", cwd=tmp_path)
        assert code == 0, err
        out[label] = json.loads(stdout.strip().splitlines()[-1])

    def tilt(r):
        g = np.asarray(r["gravity"]["vector"])
        return float(np.degrees(np.arccos(-g[2] / np.linalg.norm(g))))

    assert tilt(out["plain"]) > 10.0 and tilt(out["spring"]) < 1.0
    (spring,) = out["spring"]["effects_identified"]
    assert spring["name"] == "spring" and spring["params"]["k"] == pytest.approx(
        draw_case_parameters(case)[0]["size"], rel=0.03)
    assert out["spring"]["effects_left_out"] == ["torque_offset@2: a term of the rigid-body and friction model itself"]
    assert load_model(out["spring"]["model"]).effects[0]["name"] == "spring"
    assert all(a < b for a, b in zip(out["spring"]["validation"]["sdp"], out["plain"]["validation"]["sdp"]))


def test_effects_from_bad_files_are_one_line(tmp_path):
    from calibration.identification import make_model
    from rig.model.model_file import save_model

    rows = _synthetic_rows(n=1500, seed=3)
    data = _write(tmp_path / "d.csv", rows)
    names = list(make_model([0.0, 0.0, -9.81], 400.0).param_names())
    bare = save_model(tmp_path / "bare.json", standard=np.zeros(82), names=names, slope=400.0, gravity=[0, 0, -9.81])
    pf = save_model(tmp_path / "pf.json", standard=np.zeros(82), names=names, slope=400.0, gravity=[0, 0, -9.81],
                    extra={"effects": [{"name": "position_friction", "joint": 3,
                                        "params": {"period": 0.05, "harmonics": 1, "a_sin": [0.1], "a_cos": [0.0]}}]})
    cases = [(["--effects-from", str(tmp_path / "missing.json")], "no such model file"),
             (["--effects-from", str(bare)], "the model file has no effects to identify"),
             (["--effects-from", str(pf), "--position-friction", "auto"], "use one of them")]
    for extra, message in cases:
        code, stdout, err = rig_cli("identify", "--csv", str(data), *extra, "--no-plots", cwd=tmp_path)
        assert code != 0 and message in err + stdout, (extra, err, stdout)
        assert "Traceback" not in err + stdout
