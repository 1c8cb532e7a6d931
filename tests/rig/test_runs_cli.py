"""`rig runs` and `rig export`."""

import json
import time

import numpy as np
import pytest
from click.testing import CliRunner

from rig.cli import main
from rig.export_cli import export_csv
from rig.runs.recording import Recorder
from rig.runs.run import AbortRun, Run

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
    monkeypatch.setenv("COLUMNS", "1000")  # a wide terminal: no result is cut
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
    assert result.exit_code == 5
    assert "no run 'no-such-run'" in result.output and "rig runs" in result.output
    result = invoke("export", run.dir.name, "--csv", str(tmp_path / "x.csv"), "--arm", "PSM3")
    assert result.exit_code == 5
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
        with Run("cooperative", progress=False) as aborted:
            raise AbortRun("tension 16 N above the ceiling 12 N")
    time.sleep(0.002)
    # a run killed outright: a recording but no result.json and no stop record
    stale = logs / "29991231T235959000000Z-friction-ramp"
    stale.mkdir()
    Recorder(stale / "run.mcap").start("friction-ramp")

    result = invoke("runs")
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert lines[0].split() == ["run", "status", "duration", "arms", "result"]
    # the first column is the folder name that `rig runs RUN` and `rig export RUN` take
    assert [line.split()[0] for line in lines[1:]] == [run.dir.name, aborted.dir.name, stale.name]
    assert "completed" in lines[1] and "rel_error_j1=0.09312, rel_error_j2=0.178" in lines[1]
    assert "aborted" in lines[2] and "tension 16 N above" in lines[2]
    assert "unfinished" in lines[3]

    doc = json.loads(invoke("runs", "--json").output)
    assert [r["status"] for r in doc["runs"]] == ["completed", "aborted", "unfinished"]
    assert [r["run"] for r in doc["runs"]] == [run.dir.name, aborted.dir.name, stale.name]
    assert doc["runs"][0]["summary"]["rel_error_j2"] == 0.178  # the JSON keeps full precision
    only = json.loads(invoke("runs", "--json", "-p", "cooperative").output)["runs"]
    assert [r["procedure"] for r in only] == ["cooperative"]
    assert len(json.loads(invoke("runs", "--json", "--last", "1").output)["runs"]) == 1


def _result(logs, name, status="completed", summary=None, **extra):
    """A hand-written run folder with its result.json (no recording)."""
    run_dir = logs / name
    run_dir.mkdir(parents=True)
    doc = {"status": status, "procedure": name.split("-", 1)[1], "run_dir": str(run_dir),
           "timings": {"utc_start": "2026-11-25T13:15:38.557481+00:00",
                       "utc_stop": "2026-11-25T13:15:42.123456+00:00", "duration_s": 3.565975,
                       "steps": {"attach the object": 0.0070321234, "hold the tension while moving": 2.0489714}},
           "summary": summary or {}, **extra}
    (run_dir / "result.json").write_text(json.dumps(doc))
    return run_dir


PROVENANCE = {"arms": [{"name": "PSM1", "identity": "sim PSM1 (plant 1a2b3c4d)"}],
              "rig": "a1b2c3d4e5f6", "source": {"run": "20261125T120000000000Z-identify"},
              "package_version": "0.1.0", "time": "2026-11-25T16:00:00+00:00"}


def test_runs_shows_figures_to_four_digits_key_figures_first(logs):
    # cooperative's summary as the procedure writes it, the key figures not first
    _result(logs, "20261125T131538557481Z-cooperative",
            summary={"overshoot": 0.0384521, "max_error_during_motion": 0.10253906, "hold_reversals": 297,
                     "rms_error": 0.045101234567, "settling_time": 1.0320000000000003, "limit_cycle": False})
    _result(logs, "20261125T151058980037Z-calibrate-rcm",
            summary={"PSM1 rcm (m)": [0.48628158446168723, -6.081799602616347e-05, 0.15246635717603615]})
    out = invoke("runs").output
    coop, rcm = out.strip().splitlines()[1:]
    assert coop.split()[:4] == ["20261125T131538557481Z-cooperative", "completed", "3.6", "s"]
    result = coop.split("3.6 s", 1)[1].strip()
    assert result.startswith("rms_error=0.0451 N, max_error_during_motion=0.1025 N, settling_time=1.032 s, "
                             "limit_cycle=no, overshoot=0.03845 N")
    assert "hold_reversals=297" in result
    assert "PSM1 rcm (m)=[0.4863, -6.082e-05, 0.1525]" in rcm
    assert "0.4862815" not in out and "1.0320000" not in out


def test_runs_fits_the_result_to_the_terminal(logs, monkeypatch):
    _result(logs, "20261125T131538557481Z-cooperative",
            summary={"rms_error": 0.045101234567, "max_error_during_motion": 0.10253906, "overshoot": 0.0384521})
    monkeypatch.setenv("COLUMNS", "100")
    row = invoke("runs").output.splitlines()[1]
    assert len(row) == 100 and row.endswith("...") and "rms_error=0.0451 N" in row


def test_runs_filters_by_procedure_and_status(logs):
    _result(logs, "20261125T100000000000Z-cooperative")
    _result(logs, "20261125T100001000000Z-cooperative", status="failed",
            error="the tension never settled within 0.5 N of 5 N")
    _result(logs, "20261125T100002000000Z-identify", status="aborted", error="interrupted (Ctrl-C)")
    _result(logs, "20261125T100003000000Z-cooperative", status="dry-run")
    _result(logs, "20261125T100004000000Z-identify")

    def names(*args):
        result = invoke("runs", *args)
        assert result.exit_code == 0, result.output
        return [line.split()[0] for line in result.output.strip().splitlines()[1:]]

    assert names("--status", "failed") == ["20261125T100001000000Z-cooperative"]
    assert "the tension never settled within 0.5 N of 5 N" in invoke("runs", "-s", "failed").output
    assert names("--status", "completed,dry-run") == ["20261125T100000000000Z-cooperative",
                                                      "20261125T100003000000Z-cooperative",
                                                      "20261125T100004000000Z-identify"]
    assert names("-s", "failed", "-s", "aborted") == ["20261125T100001000000Z-cooperative",
                                                     "20261125T100002000000Z-identify"]
    assert names("-p", "cooperative", "-s", "completed,failed", "--last", "1") == [
        "20261125T100001000000Z-cooperative"]
    assert names("--procedure", "identify", "--status", "completed") == ["20261125T100004000000Z-identify"]

    bad = invoke("runs", "--status", "done")
    assert bad.exit_code == 2 and "'done' is not a status" in bad.output and "dry-run" in bad.output
    none = invoke("runs", "-p", "cooprative")
    assert none.exit_code == 0
    assert none.output.strip() == (f"no runs under {logs} match --procedure cooprative "
                                   f"(procedures with runs: cooperative, identify)")
    assert invoke("runs", "-p", "identify", "-s", "failed").output.strip() == (
        f"no runs under {logs} match --procedure identify --status failed")


def test_runs_run_shows_one_run_with_its_provenance(logs):
    run_dir = _result(logs, "20261125T160000000000Z-identify",
                      summary={"validation_sdp": 0.093123456, "validation_ols": 0.17812345,
                               "model": str(logs / "20261125T160000000000Z-identify" / "model.json")},
                      provenance=PROVENANCE)
    _result(logs, "20261125T160001000000Z-cooperative")
    for arg in (run_dir.name, str(run_dir), str(run_dir / "result.json")):
        result = invoke("runs", arg)
        assert result.exit_code == 0, result.output
        out = result.output
        assert out.startswith(f"run {run_dir.name}\n")
        lines = [" ".join(line.split()) for line in out.splitlines()]
        for expected in (f"folder {run_dir}", "procedure identify", "status completed", "source arms PSM1",
                         "started 2026-11-25 13:15:38.557 UTC", "stopped 2026-11-25 13:15:42.123 UTC",
                         "duration 3.566 s", "attach the object 0.007032 s", "hold the tension while moving 2.049 s",
                         "validation_sdp 0.09312", "validation_ols 0.1781",
                         "model 20261125T160000000000Z-identify/model.json",
                         "provenance", "arms[0].name PSM1", "arms[0].identity sim PSM1 (plant 1a2b3c4d)",
                         "rig a1b2c3d4e5f6", "source.run 20261125T120000000000Z-identify",
                         "package_version 0.1.0", "time 2026-11-25T16:00:00+00:00", "result.json " +
                         f"{(run_dir / 'result.json').stat().st_size} B"):
            assert expected in lines, (expected, out)
        assert "error" not in out
    # the list names the source arm, and nothing for a run without provenance
    rows = invoke("runs").output.strip().splitlines()
    assert rows[1].split()[:5] == [run_dir.name, "completed", "3.6", "s", "PSM1"]
    assert rows[2].split()[:5] == ["20261125T160001000000Z-cooperative", "completed", "3.6", "s"]
    assert "PSM" not in rows[2]
    doc = json.loads(invoke("runs", run_dir.name, "--json").output)
    assert doc["provenance"] == PROVENANCE and doc["arms"] == ["PSM1"]
    assert doc["timings"]["steps"]["attach the object"] == 0.0070321234


def test_runs_run_shows_a_provenance_of_another_shape(logs):
    provenance = {"arms": ["PSM1", "PSM2"], "source": {"csv": "/data/wpi-psm/train.csv", "sha256": "ab" * 32},
                  "checks": {"fit": {"condition": 123.456789, "passed": True}}, "digest": "cd" * 32}
    run_dir = _result(logs, "20261125T170000000000Z-register", provenance=provenance)
    lines = [" ".join(line.split()) for line in invoke("runs", run_dir.name).output.splitlines()]
    for expected in ("arms [PSM1, PSM2]", "source.csv /data/wpi-psm/train.csv", f"source.sha256 {'ab' * 32}",
                     "checks.fit.condition 123.5", "checks.fit.passed yes", f"digest {'cd' * 32}",
                     "source arms PSM1, PSM2"):
        assert expected in lines, (expected, lines)
    assert "PSM1,PSM2" in invoke("runs").output.splitlines()[1].split()


def test_runs_run_of_a_recorded_failure(logs):
    with pytest.raises(AbortRun):
        with Run("cooperative", parameters={"force": {"value": 5.0, "units": "N", "default": 2.0}},
                 progress=False) as run:
            with run.step("hold the tension while moving"):
                raise AbortRun("tension 16 N above the ceiling 12 N")
    result = invoke("runs", run.dir.name)
    assert result.exit_code == 0, result.output
    lines = [" ".join(line.split()) for line in result.output.splitlines()]
    for expected in ("status aborted", "error tension 16 N above the ceiling 12 N",
                     "stopped in step 'hold the tension while moving'", "force 5 N (default 2)"):
        assert expected in lines, (expected, result.output)
    assert any(line.startswith("run.mcap ") for line in lines)


def test_runs_run_errors_are_one_line(logs, tmp_path):
    _result(logs, "20261125T100000000000Z-cooperative")
    for arg, words in (("20261125T999999000000Z-cooperative",
                        ["no run '20261125T999999000000Z-cooperative'", "'rig runs' lists"]),
                       (str(tmp_path), [f"{tmp_path} is not a run folder", "'rig runs' lists"])):
        result = invoke("runs", arg)
        assert result.exit_code == 5
        assert len(result.output.strip().splitlines()) == 1, result.output
        assert all(w in result.output for w in words), result.output
        assert "Traceback" not in result.output and isinstance(result.exception, SystemExit)
    both = invoke("runs", "20261125T100000000000Z-cooperative", "--last", "2")
    assert both.exit_code == 5 and len(both.output.strip().splitlines()) == 1


def test_runs_help_explains_the_columns_and_filters():
    out = invoke("runs", "--help").output
    for words in ("[RUN]", "--procedure NAME", "--status STATUS[,STATUS]", "--last N", "--json",
                  "rig export RUN", "provenance", "dry-run", "4 significant digits"):
        assert words in out, words


def test_runs_reads_the_stop_record_when_result_json_is_missing(logs):
    with Run("register", progress=False) as run:
        pass
    (run.dir / "result.json").unlink()
    info = json.loads(invoke("runs", "--json").output)["runs"][0]
    assert info["status"] == "completed" and info["procedure"] == "register"
    detail = invoke("runs", run.dir.name)
    assert detail.exit_code == 0, detail.output
    lines = [" ".join(line.split()) for line in detail.output.splitlines()]
    assert "status completed" in lines and "summary" not in lines
    assert any(line.startswith("started 20") and line.endswith("UTC") for line in lines)


def test_no_runs(logs):
    result = CliRunner().invoke(main, ["runs"])
    assert result.exit_code == 0 and "no runs under" in result.output
