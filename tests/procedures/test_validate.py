"""`rig validate`: a model file's predicted efforts on a recording, effects included.

Known truths: efforts generated from a model file's own dynamics (rigid body, friction with
its Stribeck excess, and its effects) are predicted by that file to within the filter's
numerical error; the simulated rig's true plant predicts what the rig recorded, its hidden
hysteresis included; a run folder and the CSV `rig export` makes of it give the same
figures; without effects, the held-out figures are `rig discrepancy --model`'s baseline."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rig.cli import main

from ._cli import run_cli

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "wpi-psm" / "one_results.csv"
if not REAL.exists():
    REAL = Path("/work/shared/data/wpi-psm/one_results.csv")

RATE = 200.0
#: A tilted arm's gravity in frame 0 (m/s^2): the file's vector must be the one used.
GRAVITY = 9.81 * np.array([-0.96, 0.05, -0.24]) / np.linalg.norm([-0.96, 0.05, -0.24])
STRIBECK = {"Fst": [0.0, 0.0, 0.3], "vs": [0.01, 0.01, 0.004]}
#: One entry of each kind the controller feeds forward, an effort delay (which it does not)
#: and a payload already in the standard parameters.
EFFECTS = [
    {"name": "hysteresis", "joint": 3, "params": {"Fd": 0.5, "travel": 0.001}},
    {"name": "position_friction", "joint": 3,
     "params": {"period": 0.05, "a_sin": [0.1, 0.05], "a_cos": [0.02, -0.03]}},
    {"name": "spring", "joint": 1, "params": {"k": 0.8, "q0": 0.1}},
    {"name": "stiction", "joint": 2, "params": {"dFs": 0.3, "vs": 0.02}},
    {"name": "coulomb_asymmetry", "joint": 2, "params": {"dFc": 0.1}},
    {"name": "hysteresis", "joint": 1, "params": {"Fd": 0.15, "travel": 0.01}},
    {"name": "viscous_nonlinear", "joint": 3, "params": {"c": 20.0, "exponent": 2.0}},
    {"name": "torque_offset", "joint": 3, "params": {"offset": 0.3}},
    {"name": "payload", "joint": 3, "params": {"mass": 0.1, "com": [0.0, 0.0, -0.1], "body": "tool"},
     "applied_to": "standard_parameters"},
    {"name": "time_delay", "joint": 1, "params": {"delay": 0.01}},
]


def write_model(path, effects=(), stribeck=STRIBECK, gravity=GRAVITY, standard=None) -> Path:
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics

    dyn = PSMDynamics()
    return save_model(path, standard=dyn.standard_params() if standard is None else standard,
                      names=dyn.param_names(), slope=dyn.slope, gravity=gravity, stribeck=stribeck,
                      extra={"effects": list(effects)})


def model_efforts(model_path, q, dq, ddq) -> np.ndarray:
    """The efforts the model file describes for an exact motion: inverse dynamics (rigid
    body, rotor inertia, friction with the Stribeck excess) plus each effect's torque, in
    the file's order, on the exact state."""
    from calibration.effects import CATALOGUE
    from rig.model.model_file import load_model

    m = load_model(model_path)
    dyn = m.dynamics()
    tau = np.array([dyn.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(len(q))])
    for e in m.effects:
        if e["name"] != "payload":
            tau = tau + CATALOGUE[e["name"]].torque(e["params"], e["joint"], q, dq, tau, RATE, dyn.slope)
    return tau


def exact_motion(seed: int = 0, seconds: float = 30.0):
    from calibration.hidden_effects import trajectory

    return trajectory(seed, seconds + 1.0)(np.arange(int(seconds * RATE)) / RATE)


def write_csv(path, q, dq, tau) -> Path:
    np.savetxt(path, np.hstack([q, dq, tau]), delimiter=",", fmt="%.17g")
    return Path(path)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A model file with every kind of effect, the same file without its effects, and a
    CSV of the efforts the first one describes for an exact motion."""
    d = tmp_path_factory.mktemp("synthetic")
    with_effects = write_model(d / "with.json", EFFECTS)
    without = write_model(d / "without.json")
    q, dq, ddq = exact_motion()
    csv = write_csv(d / "motion.csv", q, dq, model_efforts(with_effects, q, dq, ddq))
    return {"with": with_effects, "without": without, "csv": csv, "q": q, "dq": dq}


def test_a_model_predicts_the_efforts_of_its_own_dynamics(synthetic):
    """Efforts generated from the model file itself: relative error ~0 on every joint, in
    both blocks; the same file without its effects is far off where the effects act. The
    JSON carries both models' figures side by side."""
    code, doc, err = run_cli("validate", "--model", str(synthetic["with"]), "--compare", str(synthetic["without"]),
                             "--csv", str(synthetic["csv"]), "--effort-lag", "0", "--json")
    assert code == 0, err
    for block in ("all", "heldout"):
        rel = np.array(doc["blocks"][block]["relative_error"])
        assert np.all(rel < 2e-3), (block, rel)
        assert np.all(np.array(doc["blocks"][block]["rms"]) < 2e-3)
    assert doc["relative_error"] == doc["blocks"]["all"]["relative_error"]
    assert doc["rms"] == doc["blocks"]["all"]["rms"]
    plain = np.array(doc["compare"]["relative_error"])
    assert np.all(plain > 0.05) and np.all(plain > 50 * np.array(doc["relative_error"])), plain
    assert set(doc["compare"]) >= {"relative_error", "rms", "blocks", "model"}
    assert len(doc["compare"]["rms"]) == 3
    assert doc["model"]["stribeck"] is True
    uses = {(e["name"], e["joint"]): e["use"] for e in doc["model"]["effects"]}
    assert uses[("payload", 3)] == "in the standard parameters"
    assert "time order" in uses[("hysteresis", 3)]
    assert "does not feed it forward" in uses[("time_delay", 1)]
    assert doc["compare"]["model"]["effects"] == []
    assert doc["summary"]["compare"] == " / ".join(f"{v:.3f}" for v in plain)
    # The side-by-side table on stderr: both models on both blocks.
    rows = [ln for ln in err.splitlines() if re.match(r"^[* ] .{36} [AB] ", ln)]
    assert [ln[39] for ln in rows] == ["A", "B", "A", "B"], err
    assert "better per joint (whole recording): A / A / A" in err
    png = Path(doc["plots"]["efforts.png"])
    assert png.parent == Path(doc["run_dir"]) and png.stat().st_size > 10_000


def test_the_stribeck_excess_and_the_gravity_of_the_file_are_used(synthetic, tmp_path):
    """The same standard parameters without the file's Stribeck excess, or with the
    untilted arm's gravity, predict the synthetic efforts worse: both are part of the
    model."""
    from calibration.datasets import load_csv
    from calibration.prediction import predict
    from rig.model.model_file import load_model

    data = load_csv(synthetic["csv"], RATE, 3)
    from calibration.discrepancy.settings import Settings

    s = Settings(effort_lag=0.0)

    def rel(path):
        return np.array(predict(load_model(path), data.q, data.dq, data.tau, RATE, s).figures("all")["relative_error"])

    exact = rel(synthetic["with"])
    no_stribeck = rel(write_model(tmp_path / "a.json", EFFECTS, stribeck=None))
    upright = rel(write_model(tmp_path / "b.json", EFFECTS, gravity=[0.0, 0.0, -9.81]))
    assert no_stribeck[2] > 100 * exact[2] and no_stribeck[2] > 1e-3
    assert np.all(upright[:2] > 100 * exact[:2]) and np.all(upright[:2] > 1e-2)


def test_stateful_effects_run_in_time_order_as_the_feedforward(synthetic):
    """The effects' share of the prediction is what `EffectCompensation` feeds forward when
    called once per sample along the recording (the Dahl states advanced step by step from
    rest); the effort delay, which the controller does not feed forward, is in the
    prediction on top."""
    from calibration.datasets import load_csv
    from calibration.discrepancy.settings import Settings
    from calibration.effects import EffectCompensation, delayed
    from calibration.prediction import predict
    from rig.model.model_file import load_model

    data = load_csv(synthetic["csv"], RATE, 3)
    s = Settings(effort_lag=0.0)   # the model's state is then the measured one itself
    fed = [e for e in EFFECTS if e["name"] != "time_delay"]
    d = Path(synthetic["csv"]).parent
    with_fed = load_model(write_model(d / "fed.json", fed))
    pred = predict(with_fed, data.q, data.dq, data.tau, RATE, s)
    comp = EffectCompensation(with_fed.effects, with_fed.slope)
    stepped = np.array([comp(data.q[k], data.dq[k]) for k in range(len(data.q))])
    np.testing.assert_allclose(pred.effects_raw, stepped, atol=1e-12)
    # The Dahl state depends on the path, not on the state alone: the recording run backwards
    # gives other torques at the same samples.
    back = EffectCompensation(with_fed.effects, with_fed.slope)
    reverse = np.array([back(data.q[k], data.dq[k]) for k in range(len(data.q) - 1, -1, -1)])[::-1]
    assert np.max(np.abs(reverse[:, 2] - stepped[:, 2])) > 0.5
    # The delay on joint 1: the model's effort (rigid body, friction and the effects before
    # it in the list) 10 ms earlier, less that effort, on top of the effects above.
    whole, fed_only = (predict(m, data.q, data.dq, data.tau, RATE, s, inertia="filtered")
                       for m in (load_model(synthetic["with"]), with_fed))
    x = fed_only.raw[:, 0]
    np.testing.assert_allclose(whole.effects_raw[:, 0] - fed_only.effects_raw[:, 0], delayed(x, 0.01 * RATE) - x,
                               atol=1e-12)


def test_heldout_figures_are_the_discrepancy_baseline(tmp_path):
    """Without effects and a Stribeck excess, the held-out block's figures are those the
    discrepancy workflow computes for a given model's baseline (the same samples, filter,
    stuck mask and inertial-term source), on a recording of the simulated rig."""
    from calibration.discrepancy.settings import Settings
    from calibration.discrepancy.workflow import Discrepancy
    from calibration.discrepancy_null import sim_model_and_base
    from calibration.hidden_effects import HiddenCase
    from tests.sim_cache import recorded
    from calibration.prediction import predict
    from rig.model.model_file import load_model

    rec, _ = recorded(HiddenCase((("spring", 1),), 4))
    m = load_model(write_model(tmp_path / "m.json", stribeck=None, gravity=[0.0, 0.0, -9.81]))
    model, base = sim_model_and_base()
    w = Discrepancy(m.dynamics(), base, rec.q, rec.dq, rec.tau, rec.rate, m.standard, Settings())
    pr = predict(m, rec.q, rec.dq, rec.tau, rec.rate, Settings())
    f = pr.figures("heldout")
    np.testing.assert_allclose(f["relative_error"], w.heldout_rel(w.baseline_pred), rtol=1e-9)
    np.testing.assert_allclose(f["rms"], w.heldout_rms(w.baseline_pred), rtol=1e-9)
    assert pr.inertia_source == w.inertia
    assert f["moving_samples"] == [len(x) for x in w.mov_ho]


def test_cli_heldout_equals_rig_discrepancy_baseline(tmp_path):
    """`rig validate --block heldout` prints what `rig discrepancy --csv X --model M` reports
    as its baseline, for a model without effects (the simulated rig's true plant on a
    recording of a hidden spring, 20 s)."""
    from calibration.hidden_effects import HiddenCase
    from tests.sim_cache import recorded

    rec, _ = recorded(HiddenCase((("spring", 1),), 4), n_samples=4000)
    csv = write_csv(tmp_path / "rec.csv", rec.q, rec.dq, rec.tau)
    model = write_model(tmp_path / "m.json", stribeck=None, gravity=[0.0, 0.0, -9.81])
    code, disc, err = run_cli("discrepancy", "--csv", str(csv), "--model", str(model), "--no-plots", "--json")
    assert code == 0, err
    code, val, err = run_cli("validate", "--csv", str(csv), "--model", str(model), "--block", "heldout",
                             "--no-plots", "--json")
    assert code == 0, err
    np.testing.assert_allclose(val["relative_error"], disc["baseline"]["heldout_rel_error"], rtol=1e-9)
    np.testing.assert_allclose(val["rms"], disc["baseline"]["heldout_rms"], rtol=1e-9)
    # The true plant's spring is missing from the file: joint 1 is the worst predicted.
    assert val["relative_error"][0] > 0.05 > max(val["relative_error"][1:])


def _record_run(rec, procedure="sim-recording"):
    """The simulated rig's recording as a run folder (/PSM1/measured_js at its rate)."""
    from rig.runs.run import Run

    with Run(procedure, progress=False) as run:
        for k in range(len(rec.q)):
            run.recorder.joint_state("/PSM1/measured_js", 1.0 + k / rec.rate, rec.q[k], rec.dq[k], rec.tau[k],
                                     ["outer_yaw", "outer_pitch", "outer_insertion"])
    return run.dir


def test_simulated_run_and_its_export_agree_and_the_true_plant_predicts_them(tmp_path):
    """A recording of the simulated rig with a hidden Dahl friction on the insertion joint:
    RUN_DIR and the CSV `rig export` writes of it give the same figures; the true plant
    (nominal parameters, the hidden hysteresis as the file's effect) predicts it within
    a few per cent on every joint, and without its effect is far off on joint 3."""
    from calibration.hidden_effects import HiddenCase
    from tests.sim_cache import recorded

    rec, truth = recorded(HiddenCase((("hysteresis", 3),), 5))
    p = truth.params[0]
    hyst = {"name": "hysteresis", "joint": 3, "params": {"Fd": p["size"], "travel": p["size"] / p["stiffness"]}}
    true_plant = write_model(tmp_path / "true.json", [hyst], stribeck=None, gravity=[0.0, 0.0, -9.81])
    rigid = write_model(tmp_path / "rigid.json", stribeck=None, gravity=[0.0, 0.0, -9.81])
    run_dir = _record_run(rec)
    csv = tmp_path / "export.csv"
    assert CliRunner().invoke(main, ["export", str(run_dir), "--csv", str(csv)]).exit_code == 0
    code, from_run, err = run_cli("validate", str(run_dir), "--model", str(true_plant), "--compare", str(rigid),
                                  "--no-plots", "--json")
    assert code == 0, err
    code, from_csv, err = run_cli("validate", "--csv", str(csv), "--model", str(true_plant), "--compare", str(rigid),
                                  "--no-plots", "--json")
    assert code == 0, err
    for a, b in ((from_run, from_csv), (from_run["compare"], from_csv["compare"])):
        for block in ("all", "heldout"):
            np.testing.assert_allclose(a["blocks"][block]["relative_error"], b["blocks"][block]["relative_error"],
                                       rtol=1e-9)
            np.testing.assert_allclose(a["blocks"][block]["rms"], b["blocks"][block]["rms"], rtol=1e-9)
    rel, plain = np.array(from_run["relative_error"]), np.array(from_run["compare"]["relative_error"])
    assert np.all(rel < 0.03), rel
    assert plain[2] > 10 * rel[2]
    np.testing.assert_allclose(plain[:2], rel[:2], rtol=1e-12)   # the effect acts on joint 3 only
    # `rig runs` lists the validation with its figures.
    code, runs, _ = run_cli("runs", "--procedure", "validate", "--json")
    summaries = [r["summary"] for r in runs["runs"]]
    assert {"block": "all", "relative_error": " / ".join(f"{v:.3f}" for v in rel),
            "compare": " / ".join(f"{v:.3f}" for v in plain)} in summaries


def test_a_time_column_csv_gives_the_same_figures(synthetic, tmp_path):
    """`--time-column` (as `rig identify` takes it): the same samples with their times."""
    data = np.loadtxt(synthetic["csv"], delimiter=",")
    timed = tmp_path / "timed.csv"
    np.savetxt(timed, np.column_stack([np.arange(len(data)) / RATE, data]), delimiter=",", fmt="%.17g")
    args = ["--model", str(synthetic["with"]), "--no-plots", "--json", "--block", "heldout"]
    _, a, _ = run_cli("validate", "--csv", str(synthetic["csv"]), *args)
    _, b, _ = run_cli("validate", "--csv", str(timed), "--time-column", *args)
    np.testing.assert_allclose(a["relative_error"], b["relative_error"], rtol=1e-9)


@pytest.mark.slow
@pytest.mark.skipif(not REAL.exists(), reason="the WPI data are not available")
def test_real_data_the_discrepancy_model_as_written(tmp_path):
    """On the real PSM recording the model `rig discrepancy` writes (rigid body and effects
    fitted together) predicts the held-out block as the workflow itself reports for the
    model as written."""
    code, disc, err = run_cli("discrepancy", "--csv", str(REAL), "--no-plots", "--json")
    assert code == 0, err
    written = (disc.get("standard_consistency") or {}).get("heldout_rms") or disc["final"]["heldout_rms"]
    code, val, err = run_cli("validate", "--csv", str(REAL), "--model", disc["model"], "--block", "heldout",
                             "--no-plots", "--json")
    assert code == 0, err
    np.testing.assert_allclose(val["rms"], written, rtol=1e-3)
    assert [e["name"] for e in val["model"]["effects"]] == [e["name"] for e in disc["effects"]]


# ------------------------------------------------------------------------------- errors
def _one_line(res) -> str:
    """The error: one line on stderr besides the run's progress lines, if a run started."""
    lines = [ln for ln in res.stderr.splitlines()
             if ln.strip() and not ln.startswith("[") and ": recording to " not in ln]
    assert res.exit_code != 0
    assert "Traceback" not in res.output and "Traceback" not in res.stderr
    assert len(lines) == 1, res.stderr
    return lines[0]


@pytest.fixture
def bad_files(tmp_path):
    files = {"missing": tmp_path / "nope.json", "binary": tmp_path / "binary.bin", "folder": tmp_path / "a-folder",
             "not json": tmp_path / "corrupt.json", "wrong kind": tmp_path / "other.json"}
    files["binary"].write_bytes(bytes(range(256)) * 8)
    files["folder"].mkdir()
    files["not json"].write_text('{"schema": "dvrk-rig/identified-model",\n "friction": ')
    files["wrong kind"].write_text(json.dumps({"hello": 1}))
    return files


@pytest.mark.parametrize("option", ["--model", "--compare"])
@pytest.mark.parametrize("kind", ["missing", "binary", "folder", "not json", "wrong kind"])
def test_a_bad_model_file_is_one_line_naming_it(option, kind, bad_files, synthetic):
    args = ["validate", "--csv", str(synthetic["csv"]), "--model", str(synthetic["with"])]
    if option == "--model":
        args[-1] = str(bad_files[kind])
    else:
        args += ["--compare", str(bad_files[kind])]
    line = _one_line(CliRunner().invoke(main, args))
    assert line.startswith("rig validate: ") and str(bad_files[kind]) in line


def test_models_that_cannot_predict_are_one_line(tmp_path, synthetic):
    from rig.model.model_file import friction_only_model, load_model
    from rig.model.model_file import StickSlip

    friction_only = friction_only_model(tmp_path / "fo.json", StickSlip(3, 1.0, -1.0), [0, 0, -9.81], 400.0, {})
    unknown = write_model(tmp_path / "unknown.json", [{"name": "magic", "joint": 3, "params": {}}])
    missing = write_model(tmp_path / "missing.json", [{"name": "hysteresis", "joint": 3, "params": {"Fd": 0.2}}])
    assert load_model(missing).effects   # a well-formed entry whose parameter is missing
    for path, words in ((friction_only, "friction-only"), (unknown, "not a catalogue effect"),
                        (missing, "'travel' missing")):
        line = _one_line(CliRunner().invoke(main, ["validate", "--csv", str(synthetic["csv"]), "--model", str(path)]))
        assert str(path) in line and words in line, line


def test_bad_recordings_and_inputs_are_one_line(tmp_path, synthetic):
    model = str(synthetic["with"])
    short = tmp_path / "short.csv"
    short.write_text("\n".join(synthetic["csv"].read_text().splitlines()[:300]) + "\n")
    truncated = tmp_path / "truncated.csv"
    lines = synthetic["csv"].read_text().splitlines()[:1000]
    truncated.write_text("\n".join(lines[:-1] + [lines[-1][:40]]) + "\n")
    cases = [
        (["--csv", str(short)], ["short.csv", "300 samples", "too few"]),
        (["--csv", str(truncated)], ["truncated.csv", "line 1000"]),
        (["--csv", str(tmp_path / "none.csv")], ["none.csv", "no such file"]),
        (["--csv", str(tmp_path)], [str(tmp_path), "folder"]),
        ([str(tmp_path / "no-run")], ["no run", "rig runs"]),
        ([str(tmp_path), "--csv", str(synthetic["csv"])], ["either RUN_DIR or --csv FILE, not both"]),
        ([], ["either RUN_DIR or --csv FILE"]),
    ]
    for args, words in cases:
        line = _one_line(CliRunner().invoke(main, ["validate", "--model", model, *args]))
        assert all(w in line for w in words), (args, line)
    line = _one_line(CliRunner().invoke(main, ["validate", "--csv", str(synthetic["csv"])]))
    assert "--model FILE" in line


def test_a_joint_that_never_moves_is_one_line(tmp_path, synthetic):
    data = np.loadtxt(synthetic["csv"], delimiter=",")
    # The insertion joint's motion 300 times smaller: it never leaves its deadband.
    data[:, 2] = data[:, 2].mean() + (data[:, 2] - data[:, 2].mean()) / 300.0
    data[:, 5] /= 300.0
    path = write_csv(tmp_path / "stuck.csv", data[:, :3], data[:, 3:6], data[:, 6:])
    line = _one_line(CliRunner().invoke(main, ["validate", "--csv", str(path), "--model", str(synthetic["with"])]))
    assert "joint 3" in line and "deadband" in line


def test_help_states_units_and_steps():
    res = CliRunner().invoke(main, ["validate", "--help"])
    assert res.exit_code == 0
    text = " ".join(res.output.split())
    for words in ("N m for joints 1-2, N for joint 3", "relative error", "[Hz;", "[ms;", "--compare", "--block"):
        assert words in text, words
    res = CliRunner().invoke(main, ["validate", "--steps"])
    assert res.exit_code == 0 and res.output.startswith("1. load the recording")
    assert "validate" in CliRunner().invoke(main, ["--help"]).output


def test_the_mass_matrix_of_the_prediction_is_the_model_s():
    """The mass matrix the prediction's inertial term and a backlash's crossing use (the
    regressor's change for unit accelerations, times the parameters, plus the rotor
    inertias) is the model's M(q); its zero-acceleration effort is C(q, dq) dq + g(q)."""
    from calibration.prediction import _rigid_body
    from rig.model.psm_dynamics import PSMDynamics

    dyn = PSMDynamics(gravity=GRAVITY)
    rng = np.random.default_rng(1)
    q = rng.uniform([-1.0, -0.6, 0.05], [1.0, 0.6, 0.2], (20, 3))
    dq = rng.uniform(-1.0, 1.0, (20, 3))
    static, mass = _rigid_body(dyn, dyn.standard_params(), q, dq)
    for k in range(len(q)):
        np.testing.assert_allclose(mass[k] + np.diag(dyn.Ia), dyn.mass_matrix(q[k]), atol=1e-12)
        np.testing.assert_allclose(static[k], dyn.bias(q[k], dq[k]), atol=1e-12)
