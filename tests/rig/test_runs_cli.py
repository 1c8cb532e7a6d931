"""`rig runs` and `rig export`."""

import json
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rig.cli import main
from rig.records import Recorder
from rig.run import AbortRun, Run
from rig.runs_cli import export_csv

JOINTS = 7  # like the dVRK PSM and the wpi-psm file


def _q(t):
    """Known joint trajectories: linear ones (interpolation is exact) and a slow sine."""
    t = np.asarray(t, dtype=float)
    cols = [0.1 + 0.5 * t, -0.3 * t, 0.05 + 0.01 * t, np.sin(2 * np.pi * 0.5 * t)]
    cols += [k * 0.01 * t for k in range(1, JOINTS - 3)]
    return np.stack(cols, axis=-1)


@pytest.fixture
def logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    return tmp_path / "logs"


def _record(run: Run, seconds=0.5, rate=1000.0, t0=2.0):
    for i in range(int(seconds * rate) + 1):
        t = t0 + i / rate
        q = _q(t)
        run.recorder.joint_state("/PSM1/measured_js", t, q, 2 * q, -q, [f"j{k}" for k in range(1, JOINTS + 1)])
        run.recorder.joint_state("/PSM2/measured_js", t, q[:3], q[:3], q[:3])


def invoke(*args):
    return CliRunner().invoke(main, list(args))


def test_export_round_trip(logs, tmp_path):
    with Run("identify", progress=False) as run:
        _record(run)
    out = tmp_path / "psm1.csv"
    result = invoke("export", run.dir.name, "--csv", str(out), "--rate", "200")
    assert result.exit_code == 0, result.output
    assert "wrote 101 rows x 21 columns (7 joints, q|dq|tau) at 200 Hz from 501 samples" in result.output
    table = np.loadtxt(out, delimiter=",")
    assert table.shape == (101, 3 * JOINTS)
    assert not out.read_text().startswith("j")  # no header, like the wpi-psm file
    t = 2.0 + np.arange(101) / 200.0
    q = _q(t)
    np.testing.assert_allclose(table[:, :JOINTS], q, atol=1e-12)  # grid points are samples
    np.testing.assert_allclose(table[:, JOINTS:2 * JOINTS], 2 * q, atol=1e-12)
    np.testing.assert_allclose(table[:, 2 * JOINTS:], -q, atol=1e-12)

    # Between samples: exact for the linear joints, within the chord error for the sine.
    summary = export_csv(run.dir, tmp_path / "off.csv", rate=300.0)
    table = np.loadtxt(tmp_path / "off.csv", delimiter=",")
    t = 2.0 + np.arange(summary["rows"]) / 300.0
    assert summary["rows"] == 151 and summary["warnings"] == []
    np.testing.assert_allclose(table[:, [0, 1, 2, 4, 5, 6]], _q(t)[:, [0, 1, 2, 4, 5, 6]], atol=1e-12)
    chord = (2 * np.pi * 0.5) ** 2 * (1e-3) ** 2 / 8  # max |f''| h^2 / 8
    assert np.max(np.abs(table[:, 3] - _q(t)[:, 3])) <= chord * 1.01

    # The other arm, by folder path, with its three joints.
    assert invoke("export", str(run.dir), "--csv", str(tmp_path / "psm2.csv"), "--arm", "PSM2").exit_code == 0
    assert np.loadtxt(tmp_path / "psm2.csv", delimiter=",").shape == (101, 9)


def test_export_errors_are_clear(logs, tmp_path):
    with Run("identify", progress=False) as run:
        _record(run, seconds=0.01)
    result = invoke("export", "no-such-run", "--csv", str(tmp_path / "x.csv"))
    assert result.exit_code == 1
    assert "no run 'no-such-run'" in result.output and "rig runs" in result.output
    result = invoke("export", run.dir.name, "--csv", str(tmp_path / "x.csv"), "--arm", "PSM3")
    assert result.exit_code == 1
    assert "/PSM3/measured_js is not in the recording" in result.output
    assert "/PSM1/measured_js, /PSM2/measured_js" in result.output
    result = invoke("export", run.dir.name, "--csv", str(tmp_path / "x.csv"), "--rate", "0")
    assert result.exit_code == 2
    assert not (tmp_path / "x.csv").exists()


def test_an_unfinalised_recording_still_exports(logs, tmp_path):
    run_dir = logs / "20260101T000000000000Z-identify"
    run_dir.mkdir(parents=True)
    rec = Recorder(run_dir / "run.mcap", chunk_size=2048)
    for i in range(400):
        rec.joint_state("/PSM1/measured_js", i * 1e-3, [i * 1e-3] * 3, [1.0] * 3, [0.0] * 3)
    rec.close()
    data = (run_dir / "run.mcap").read_bytes()
    (run_dir / "run.mcap").write_bytes(data[: int(len(data) * 0.6)])  # killed by SIGKILL, say
    result = invoke("export", str(run_dir), "--csv", str(tmp_path / "cut.csv"), "--rate", "1000")
    assert result.exit_code == 0, result.output
    assert "is unfinalised (file ends early" in result.output
    table = np.loadtxt(tmp_path / "cut.csv", delimiter=",")
    assert 50 < len(table) < 400
    np.testing.assert_allclose(table[:, 0], np.arange(len(table)) * 1e-3, atol=1e-12)


def test_runs_lists_oldest_first_with_status_and_key_result(logs):
    with Run("identify", progress=False) as run:
        run.finish({"summary": {"rel_error_j1": 0.0931234, "rel_error_j2": 0.178}})
    time.sleep(0.002)
    with pytest.raises(AbortRun):
        with Run("cooperative", progress=False):
            raise AbortRun("tension 16 N above the ceiling 12 N")
    time.sleep(0.002)
    # a run killed outright: a recording but no result.json and no stop record
    stale = logs / "29991231T235959000000Z-friction-ramp"
    stale.mkdir()
    Recorder(stale / "run.mcap").start("friction-ramp")

    result = invoke("runs")
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert lines[0].split() == ["time", "(UTC)", "procedure", "status", "duration", "result"]
    assert "identify" in lines[1] and "completed" in lines[1]
    assert "rel_error_j1=0.09312, rel_error_j2=0.178" in lines[1]
    assert "cooperative" in lines[2] and "aborted" in lines[2] and "tension 16 N above" in lines[2]
    assert "friction-ramp" in lines[3] and "unfinished" in lines[3] and "2999-12-31 23:59:59" in lines[3]

    doc = json.loads(invoke("runs", "--json").output)
    assert [r["status"] for r in doc["runs"]] == ["completed", "aborted", "unfinished"]
    assert doc["runs"][0]["summary"]["rel_error_j2"] == 0.178
    only = json.loads(invoke("runs", "--json", "-p", "cooperative").output)["runs"]
    assert [r["procedure"] for r in only] == ["cooperative"]
    assert len(json.loads(invoke("runs", "--json", "--last", "1").output)["runs"]) == 1


def test_runs_reads_the_stop_record_when_result_json_is_missing(logs):
    with Run("register", progress=False) as run:
        pass
    (run.dir / "result.json").unlink()
    info = json.loads(invoke("runs", "--json").output)["runs"][0]
    assert info["status"] == "completed" and info["procedure"] == "register"


def test_no_runs(logs):
    result = CliRunner().invoke(main, ["runs"])
    assert result.exit_code == 0 and "no runs under" in result.output
