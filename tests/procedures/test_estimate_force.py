"""`rig estimate-force`: the tip force over a recording (issue 47), against the simulated
rig's known truth: a spring of known stiffness pulling on PSM1's tip while it moves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.force_truth import pulled_recording

from ._cli import run_cli


def _csv(path: Path, q, dq, tau) -> Path:
    np.savetxt(path, np.hstack([q, dq, tau]), delimiter=",", fmt="%.12g")
    return path


def _nominal_model(path: Path) -> Path:
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics

    dyn = PSMDynamics()
    return save_model(path, standard=dyn.standard_params(), names=dyn.param_names(), slope=dyn.slope,
                      gravity=[0.0, 0.0, -9.81])


@pytest.fixture(scope="module")
def pulled():
    return pulled_recording(stretch=0.002, seconds=4.0, moving_from=0.5)


def test_the_mean_pull_of_a_known_spring_is_found(pulled, tmp_path):
    rate, q, dq, tau, true = pulled
    keep = slice(int(1.0 * rate), None)          # the observer started at rest: its first second left out
    csv = _csv(tmp_path / "pulled.csv", q[keep], dq[keep], tau[keep])
    model = _nominal_model(tmp_path / "model.json")
    code, doc, err = run_cli("estimate-force", "--csv", str(csv), "--model", str(model), "--joints", "3",
                             "--rate", f"{rate:g}", "--no-plots", "--json")
    assert code == 0, err
    want = true[keep].mean(axis=0)
    assert np.linalg.norm(want) > 3.0
    np.testing.assert_allclose(doc["mean_force"], want, atol=0.25)
    assert doc["mean_magnitude"] == pytest.approx(np.linalg.norm(doc["mean_force"]))
    assert len(doc["spread"]) == 3 and "joint3_static" in doc["flagged_share"]
    table = np.loadtxt(doc["files"]["csv"], delimiter=",", skiprows=1)
    assert table.shape == (len(q[keep]), 10)
    np.testing.assert_allclose(table[:, 1:4].mean(axis=0), doc["mean_force"], atol=1e-3)


def test_no_object_no_force_and_a_run_folder_gives_the_csvs_figures(tmp_path):
    from rig.runs.run import Run

    rate, q, dq, tau, _ = pulled_recording(stretch=None, seconds=3.0, moving_from=0.5)
    model = _nominal_model(tmp_path / "model.json")
    csv = _csv(tmp_path / "free.csv", q, dq, tau)
    code, doc, err = run_cli("estimate-force", "--csv", str(csv), "--model", str(model), "--joints", "3",
                             "--rate", f"{rate:g}", "--no-plots", "--json")
    assert code == 0, err
    assert doc["mean_magnitude"] < 0.15, doc["mean_force"]
    with Run("sim-recording", progress=False) as run:
        for k in range(len(q)):
            run.recorder.joint_state("/PSM1/measured_js", 1.0 + k / rate, q[k], dq[k], tau[k],
                                     ["outer_yaw", "outer_pitch", "outer_insertion"])
    code, from_run, err = run_cli("estimate-force", str(run.dir), "--model", str(model), "--rate", f"{rate:g}",
                                  "--no-plots", "--json")
    assert code == 0, err
    np.testing.assert_allclose(from_run["mean_force"], doc["mean_force"], atol=0.02)


def test_inputs_it_cannot_use_are_one_line(tmp_path):
    model = _nominal_model(tmp_path / "model.json")
    code, _, err = run_cli("estimate-force", "--csv", str(tmp_path / "none.csv"), "--model", str(model))
    assert code == 5 and "no such file" in err and "Traceback" not in err
    code, _, err = run_cli("estimate-force", "--csv", str(tmp_path / "none.csv"))
    assert code == 2 and "--model" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    code, _, err = run_cli("estimate-force", "--csv", str(bad), "--model", str(model))
    last = err.strip().splitlines()[-1]
    assert code == 5 and "Traceback" not in err and last.startswith("rig estimate-force: ") and "bad.csv" in last, err
    code, _, err = run_cli("estimate-force", str(tmp_path / "no-such-run"))
    assert code == 5 and "Traceback" not in err


def test_help_states_units():
    code, _, _ = run_cli("estimate-force", "--help")
    from click.testing import CliRunner

    from rig.cli import main

    text = CliRunner().invoke(main, ["estimate-force", "--help"]).output
    assert code == 0 and "[Hz" in text and "N" in text and "base frame" in text
