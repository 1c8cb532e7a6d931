"""`rig cooperative` with the model's tension estimate (issue 47): recorded beside the load
cell in every run, and the loop closed on it (`--tension-source model`), the cell then only
judging; a rig without a load cell runs it."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from rig.cli import main
from rig.runs.recording import read_recording

SHORT = ["--force", "5", "--duration", "3", "--settle", "1.5", "--hold-after", "1", "--json"]


def _invoke(*args):
    res = CliRunner().invoke(main, [*args])
    lines = [line for line in res.stdout.strip().splitlines() if line.startswith("{")]
    return res, (json.loads(lines[-1]) if lines else None)


# the spring on the estimate runs by default over the wire (tests/hil/test_chain.py); the
# string, which drifted off after its move before the stretch filter, in-process here
@pytest.mark.parametrize("obj", [pytest.param("spring", marks=pytest.mark.slow), "string"])
def test_the_loop_closes_on_the_estimate_and_the_cell_judges_it(obj):
    res, data = _invoke("cooperative", *SHORT, "--object", obj, "--tension-source", "model")
    # completed: within the tolerance while moving and through the hold after the move,
    # where every joint sticks and the object's stretch carries the estimate (a string
    # on the torques alone drifted 0.5 N off the cell there)
    assert res.exit_code == 0, res.output
    assert data["status"] == "completed"
    est = data["tension_estimate"]
    assert est["source"] == "model" and est["loop_closed_on"] == "model estimate"
    # the estimate against the cell while moving
    assert est["rms_difference"] < 0.3 and est["max_difference"] < 0.6 and abs(est["bias"]) < 0.2, est
    # max_error_during_motion is the cell's, judged against the thesis' 0.5 N
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"))
    cell = rec.messages["/loadcell/force"]
    assert len(cell) > 1000
    assert data["max_error_during_motion"] < 0.5
    for topic in ("/cooperative/tension_estimate", "/cooperative/tension_estimate_torques",
                  "/cooperative/tension_estimate_spread"):
        assert topic in rec.counts()
    with open(os.path.join(data["run_dir"], "result.json")) as f:
        assert json.load(f)["tension_estimate"]["rms_difference"] == est["rms_difference"]


def test_a_rig_without_a_load_cell_runs_on_the_estimate_and_refuses_the_cell_source(tmp_path):
    cfg = tmp_path / "rig.toml"
    cfg.write_text('[loadcell]\ndriver = "none"\n')
    res, data = _invoke("--config", str(cfg), "cooperative", *SHORT)
    assert res.exit_code == 3 and "--tension-source model" in res.output
    res, data = _invoke("--config", str(cfg), "cooperative", *SHORT, "--tension-source", "model")
    assert res.exit_code in (0, 4), res.output
    assert data["tension_estimate"]["loop_closed_on"] == "model estimate"
    assert "no load cell" in data["tension_estimate"]["note"]
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"))
    assert "/loadcell/force" not in rec.counts()
    # the tension the loop held is the estimate's (no truth here; bench_tension_estimate judges
    # the loop against a cell): it stays within a newton of the set-point on this faster move
    assert data["max_error_during_motion"] < 1.0
    est = np.array([m.data for _, m in rec.messages["/cooperative/tension_estimate"]])
    assert abs(np.median(est[len(est) // 2:]) - 5.0) < 0.3
