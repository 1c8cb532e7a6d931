"""`rig loadcell-calibrate` reports like every procedure (issue 36, point 9): its steps and
its end line on stderr, its report on stdout (stderr with --json), a recorded run whose
duration and key figure `rig runs` shows."""

from __future__ import annotations

import json

from click.testing import CliRunner

from rig.cli import main
from rig.devices.loadcell_calibrations import load_latest_calibration
from rig.runs.recording import read_recording

#: the list's width when stdout is not a terminal (the issue's target)
LIST_WIDTH = 120


def _calibrate(*args: str):
    return CliRunner().invoke(main, ["loadcell-calibrate", "--seconds", "0.3", *args])


def test_steps_and_the_completed_line_on_stderr_the_report_on_stdout():
    res = _calibrate()
    assert res.exit_code == 0, res.output
    out, err = res.stdout, res.stderr
    assert "[1/6] connect to the load cell" in err and "[6/6] check the force with mass 2 done in" in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("rig loadcell-calibrate: completed in ") and "loadcell-calibrate)" in last, last
    assert "[1/" not in out and "completed in" not in out
    assert out.startswith("calibration: ") and "check with 0.5 kg:" in out and "saved " in out

    # a recorded run: start and stop records, the check's forces, a result with its timings
    doc = json.loads(CliRunner().invoke(main, ["runs", "--json"]).stdout)
    (info,) = doc["runs"]
    assert info["status"] == "completed" and info["duration_s"] > 0
    run_dir = info["run_dir"]
    rec = read_recording(f"{run_dir}/run.mcap")
    assert rec.finalised and rec.stop["status"] == "completed"
    assert rec.counts()["/loadcell/force"] > 10
    result = json.loads(open(f"{run_dir}/result.json").read())
    assert set(result["timings"]["steps"]) == {"connect to the load cell", "tare with mass 1 hanging",
                                               "average counts with mass 1", "average counts with mass 2",
                                               "fit the two-point calibration", "check the force with mass 2"}
    # sealed as before: a later run takes it
    assert load_latest_calibration().newtons_per_count == result["calibration"]["newtons_per_count"]

    # the list: a duration and the check's error first
    lines = CliRunner().invoke(main, ["runs"]).stdout.splitlines()
    assert len(lines) == 2 and len(lines[1]) <= LIST_WIDTH
    assert f"{info['duration_s']:.1f} s" in lines[1] and "check_error=" in lines[1], lines[1]


def test_json_keeps_stdout_for_the_document():
    res = _calibrate("--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["status"] == "completed" and doc["procedure"] == "loadcell-calibrate"
    assert "summary" in doc and doc["summary"]["check_error"] == doc["check"]["error_n"]
    assert "calibration: " in res.stderr and "rig loadcell-calibrate: completed in " in res.stderr


def test_a_port_that_is_not_there_fails_in_one_line_and_is_recorded(tmp_path):
    res = _calibrate("--port", str(tmp_path / "ttyNOPE"))
    assert res.exit_code != 0 and "Traceback" not in res.output
    last = res.stderr.strip().splitlines()[-1]
    assert res.exit_code == 3  # a device that cannot be reached aborts the run, as in every procedure
    assert "ttyNOPE" in last and "aborted:" in last and "run folder" in last, last
    doc = json.loads(CliRunner().invoke(main, ["runs", "--json"]).stdout)
    (info,) = doc["runs"]
    assert info["status"] == "aborted" and "ttyNOPE" in info["error"]
