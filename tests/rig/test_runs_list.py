"""`rig runs` (issue 36, point 6): lines that fit a terminal, a cooperative run's setup
(object, mode, move, master, rate) and arms, a load-cell calibration's duration and figure,
and an arm that went to FAULT not called held (point 8)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from rig.cli import main
from rig.runs.run import AbortRun, Run

#: the list's width when stdout is not a terminal (the issue's target)
LIST_WIDTH = 120


def _rig(*args: str):
    return CliRunner().invoke(main, list(args))


def _cooperative(monkeypatch, *args: str):
    """`rig cooperative ARGS` in-process, short; argv as the command line records it."""
    argv = ["cooperative", "--force", "5", "--duration", "1", "--settle", "0.5", "--hold-after", "0", *args]
    monkeypatch.setattr(sys, "argv", [str(Path(sys.executable).with_name("rig")), *argv])
    res = CliRunner().invoke(main, argv)
    assert "Traceback" not in res.output, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    return res


def _list(monkeypatch, *args: str) -> list[str]:
    monkeypatch.delenv("COLUMNS", raising=False)  # not a terminal: the list's own width
    res = _rig("runs", *args)
    assert res.exit_code == 0, res.output
    return res.stdout.splitlines()


def _rows(lines: list[str]) -> dict[str, str]:
    """Each run's text in the list (its continuation lines joined), by run name."""
    rows: dict[str, str] = {}
    name = None
    for line in lines[1:]:
        if not line.startswith(" "):
            name = line.split()[0]
            rows[name] = line
        else:
            rows[name] += " " + line.strip()
    return rows


@pytest.fixture(scope="module")
def two_objects(tmp_path_factory):
    """A spring run (impedance, PSM2 moving along x) and a string run (position mode,
    PSM1 moving along y), recorded by the real procedure in one folder."""
    logs = tmp_path_factory.mktemp("coop") / "logs"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RIG_LOGS", str(logs))
        _cooperative(mp, "--object", "spring", "--move", "0.02,0,0")
        _cooperative(mp, "--object", "string", "--mode", "position", "--move", "0,0.01,0", "--master", "PSM1")
    runs = sorted(p.name for p in logs.iterdir())
    assert len(runs) == 2, runs
    return logs, runs


def test_the_list_tells_a_spring_run_from_a_string_run_in_120_columns(two_objects, monkeypatch):
    logs, (spring, string) = two_objects
    monkeypatch.setenv("RIG_LOGS", str(logs))
    lines = _list(monkeypatch)
    assert all(len(line) <= LIST_WIDTH for line in lines), max(lines, key=len)
    rows = _rows(lines)
    assert set(rows) == {spring, string}
    for run, words in ((spring, ("PSM1,PSM2", "spring 5 N", "impedance", "PSM2 moves +20,0,0 mm", "1000 Hz")),
                       (string, ("PSM1,PSM2", "string 5 N", "position", "PSM1 moves 0,+10,0 mm", "1000 Hz"))):
        for word in words:
            assert word in rows[run], (word, rows[run])
    # --wide: one whole line per run, as long as it needs
    wide = _list(monkeypatch, "--wide")
    assert len(wide) == 3 and all(not line.startswith(" ") for line in wide)
    assert "1000 Hz: " in wide[1] and "1000 Hz: " in wide[2]


def test_the_setup_in_json_and_in_the_detail(two_objects, monkeypatch):
    logs, (spring, string) = two_objects
    monkeypatch.setenv("RIG_LOGS", str(logs))
    doc = json.loads(_rig("runs", "--json").stdout)
    setups = {r["run"]: r["setup"] for r in doc["runs"]}
    assert setups[spring]["object"] == "spring" and setups[string]["object"] == "string"
    assert setups[spring]["mode"] == "impedance" and setups[string]["mode"] == "position"
    assert setups[spring]["master"] == "PSM2" and setups[string]["master"] == "PSM1"
    assert setups[spring]["move_m"] == [0.02, 0.0, 0.0] and setups[string]["move_m"] == [0.0, 0.01, 0.0]
    assert setups[spring]["rate_hz"] == setups[string]["rate_hz"] == 1000.0
    assert {r["run"]: r["arms"] for r in doc["runs"]} == {spring: ["PSM1", "PSM2"], string: ["PSM1", "PSM2"]}
    detail = [" ".join(line.split()) for line in _rig("runs", string).stdout.splitlines()]
    for expected in ("object string, 5 N of tension", "mode position", "master PSM1", "move 0, 10, 0 mm (world frame)",
                     "loop rate 1000 Hz"):
        assert expected in detail, (expected, detail)


def test_an_aborted_cooperative_run_keeps_its_setup(monkeypatch, tmp_path):
    """Aborted before it wrote its figures: the setup comes from the start record."""
    res = _cooperative(monkeypatch, "--object", "string", "--tension-ceiling", "5.05", "--move", "0,0,0.01")
    assert res.exit_code != 0
    rows = _rows(_list(monkeypatch))
    (row,) = rows.values()
    for word in ("aborted", "PSM1,PSM2", "string 5 N", "impedance", "PSM2 moves 0,0,+10 mm", "1000 Hz", "ceiling"):
        assert word in row, (word, row)


def test_a_long_list_is_cut_not_wrapped_past_the_width(monkeypatch, tmp_path):
    """The widest run name there is, three arms and a long error: still 120 columns."""
    logs = tmp_path / "logs"
    run = logs / "20261127T000000000000Z-loadcell-calibrate"
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({
        "status": "failed", "error": "x" * 300, "timings": {"duration_s": 1234.5},
        "provenance": {"arms": [{"name": "PSM1"}, {"name": "PSM2"}, {"name": "PSM3"}]}}))
    lines = _list(monkeypatch)
    assert all(len(line) <= LIST_WIDTH for line in lines)
    assert lines[1].endswith("...") and "PSM1,PSM2,PSM3" in lines[1]


def test_a_calibration_written_before_timings_shows_its_duration_and_figure(monkeypatch, tmp_path):
    """result.json of a loadcell-calibrate run as it was written before it was a recorded run."""
    run = tmp_path / "logs" / "20261120T101500000000Z-loadcell-calibrate"
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({
        "procedure": "loadcell-calibrate", "status": "completed",
        "started": "2026-11-20T10:15:00+00:00", "finished": "2026-11-20T10:15:05.500000+00:00",
        "calibration": {"newtons_per_count": 0.00305, "zero_counts": 137.0},
        "check": {"error_n": -0.0012, "std_n": 0.0047}}))
    (row,) = _rows(_list(monkeypatch)).values()
    assert "5.5 s" in row and "check_error=-0.0012 N" in row, row


class _FaultedArm:
    """A dVRK arm (drivers.arm.dvrk_arm) gone to FAULT: it takes the hold command, obeys nothing."""

    def __init__(self, name: str):
        from drivers.arm.crtk import OperatingState

        self.name = name
        self.state = OperatingState(t=0.0, state="FAULT", is_homed=True, is_busy=False)

    def hold(self):
        pass

    def operating_state(self):
        return self.state


class _Arm:
    def __init__(self, name: str):
        self.name = name

    def hold(self):
        pass


def test_an_arm_in_fault_is_not_held(monkeypatch, tmp_path, capsys):
    with pytest.raises(AbortRun):
        with Run("friction-ramp", progress=True) as run:
            run.claim(_FaultedArm("PSM1"))
            run.claim(_Arm("PSM2"))
            raise AbortRun("/PSM1/operating_state: PSM1 went to FAULT during the run (FAULT, homed)")
    assert "rig friction-ramp: PSM1 not held: PSM1 is FAULT, homed" in capsys.readouterr().err
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["held"] == ["PSM2"]
    assert saved["hold_errors"][0]["arm"] == "PSM1" and saved["hold_errors"][0]["state"] == "FAULT, homed"
    detail = [" ".join(line.split()) for line in _rig("runs", run.dir.name).stdout.splitlines()]
    assert "arms held PSM2" in detail, detail
    assert any(line.startswith("not held PSM1 is FAULT, homed: it obeys no command") for line in detail), detail


class _ArmWhoseFaultIsOnItsWay:
    """A dVRK arm that went to FAULT an instant before another device ended the run: its
    FAULT event is not in yet (operating_state still says ENABLED), its operating_state
    service answers FAULT."""

    def __init__(self, name: str):
        from drivers.arm.crtk import OperatingState

        self.name = name
        self.asked = []
        self.last = OperatingState(t=1.0, state="ENABLED", is_homed=True, is_busy=False)
        self.now = OperatingState(t=1.002, state="FAULT", is_homed=True, is_busy=False)

    def hold(self):
        pass

    def operating_state(self):
        return self.last

    def confirm_state(self, timeout):
        self.asked.append(timeout)
        return self.now


def test_an_arm_is_asked_its_state_before_it_is_listed_held(monkeypatch, tmp_path, capsys):
    faulted, fine = _ArmWhoseFaultIsOnItsWay("PSM1"), _ArmWhoseFaultIsOnItsWay("PSM2")
    fine.now = fine.last
    with pytest.raises(AbortRun):
        with Run("cooperative", progress=False) as run:
            run.claim(faulted)
            run.claim(fine)
            raise AbortRun("tension 24.5 N above the ceiling 15.00 N")
    assert faulted.asked and fine.asked and all(0 < t <= 1.0 for t in faulted.asked + fine.asked)
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["held"] == ["PSM2"]
    assert [e["arm"] for e in saved["hold_errors"]] == ["PSM1"] and saved["hold_errors"][0]["state"] == "FAULT, homed"


def test_a_run_whose_fault_names_an_arm_in_fault_does_not_call_it_held(monkeypatch, tmp_path):
    """The fault that ended a run is recorded with its fields (arm, state): an arm it names
    in FAULT is not listed held, whatever the list says."""
    run = tmp_path / "logs" / "20261126T120000000000Z-friction-ramp"
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({
        "status": "aborted", "held": ["PSM1"], "fault": {"arm": "PSM1", "state": "FAULT"},
        "error": "/PSM1/operating_state: PSM1 went to FAULT during the run (FAULT, homed): PSM1: joint 1 at "
                 "1.62 rad, past its limit; it no longer obeys commands"}))
    detail = [" ".join(line.split()) for line in _rig("runs", run.name).stdout.splitlines()]
    assert not any(line.startswith("arms held") for line in detail), detail
    assert any(line.startswith("not held PSM1 is FAULT") for line in detail), detail


def test_a_run_records_the_fields_of_the_fault_that_ended_it(monkeypatch, tmp_path):
    from drivers.arm.crtk import ArmFault, OperatingState
    from rig.runs.safety import SafetyLimits
    import numpy as np

    with pytest.raises(AbortRun):
        with Run("cooperative", progress=False) as run:
            SafetyLimits().check_effort("PSM2", np.array([0.0, 9.0, 0.0]))
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["fault"] == {"arm": "PSM2", "joint": 2, "limit": "commanded effort"}
    fault = ArmFault("PSM1 went to FAULT", "/PSM1/operating_state",
                     OperatingState(t=0.0, state="FAULT", is_homed=True, is_busy=False), arm="PSM1")
    with pytest.raises(ArmFault):
        with Run("cooperative", progress=False) as run:
            raise fault
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["fault"] == {"arm": "PSM1", "state": "FAULT"}
