"""The run engine: folders, documents, safe stop on every kind of ending, CLI helpers."""

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from rig.commands.abort import exit_on_abort
from rig.commands.options import json_option
from rig.commands.parameters import Parameter, resolve
from rig.commands.report import emit_result
from rig.runs.recording import read_recording
from rig.runs.run import AbortRun, Run

TARGET = Path(__file__).with_name("run_kill_target.py")


class FakeArm:
    def __init__(self, name, fail=None, on_hold=None):
        self.name = name
        self.fail = fail
        self.on_hold = on_hold
        self.holds = 0

    def hold(self):
        self.holds += 1
        if self.on_hold:
            self.on_hold()
        if self.fail:
            raise self.fail


@pytest.fixture
def logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    return tmp_path / "logs"


def _only_run(logs: Path) -> Path:
    runs = [p for p in logs.iterdir() if p.is_dir()]
    assert len(runs) == 1, runs
    return runs[0]


def test_a_completed_run_writes_its_documents(logs):
    params = resolve([Parameter("rate", 500.0, "Hz", "Sample rate", minimum=1.0)], {})
    arm = FakeArm("PSM1")
    out = io.StringIO()
    with Run("identify", parameters=params, config={"arms": ["PSM1"]}, seed=7,
             steps=["excite", "fit"], stream=out) as run:
        assert run.dir.parent == logs and run.dir.name.endswith("Z-identify")
        assert run.claim(arm) is arm and run.claim(arm) is arm  # claimed once
        with run.step("excite", total=50) as step:
            for i in range(50):
                run.recorder.joint_state("/PSM1/measured_js", i * 0.002, [i, 0, 0], [0, 0, 0], [0, 0, 0])
                step.advance()
        with run.step("fit"):
            pass
        doc = run.finish({"summary": {"rms_nm": 0.12}, "params": [1.0, float("nan")]})

    assert arm.holds == 1  # the engine leaves every arm it moved holding
    assert doc is run.result and doc["status"] == "completed"
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["status"] == "completed" and saved["procedure"] == "identify"
    assert saved["run_dir"] == str(run.dir)
    assert saved["summary"] == {"rms_nm": 0.12}
    assert saved["params"] == [1.0, None]  # NaN is not JSON: written as null
    assert set(saved["timings"]) == {"utc_start", "utc_stop", "duration_s", "steps"}
    assert set(saved["timings"]["steps"]) == {"excite", "fit"}
    assert saved["held"] == ["PSM1"] and "error" not in saved

    rec = read_recording(run.dir / "run.mcap")
    assert rec.finalised
    assert rec.start["procedure"] == "identify" and rec.start["seed"] == 7
    assert rec.start["parameters"]["rate"] == {"value": 500.0, "units": "Hz", "default": 500.0,
                                               "help": "Sample rate"}
    assert rec.start["config"] == {"arms": ["PSM1"]}
    assert rec.stop["status"] == "completed" and rec.stop["error"] == ""
    assert rec.stop["counts"] == {"/PSM1/measured_js": 50}
    text = out.getvalue()
    assert "[1/2] excite ..." in text and "[2/2] fit done in" in text and "50/50" in text


def test_an_abort_holds_the_arms_finalises_and_reraises(logs):
    arms = [FakeArm("PSM1"), FakeArm("PSM2")]
    with pytest.raises(AbortRun) as caught:
        with Run("cooperative", progress=False) as run:
            for a in arms:
                run.claim(a)
            with run.step("track force"):
                run.recorder.tension("/loadcell/force", 0.1, 16.0)
                raise AbortRun("tension 16.0 N above the ceiling 12.0 N")
    assert [a.holds for a in arms] == [1, 1]
    assert caught.value.run_dir == run.dir
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["status"] == "aborted"
    assert saved["error"] == "tension 16.0 N above the ceiling 12.0 N"
    assert saved["step"] == "track force"
    rec = read_recording(run.dir / "run.mcap")
    assert rec.stop["status"] == "aborted" and rec.stop["error"] == saved["error"]
    assert rec.stop["held"] == ["PSM1", "PSM2"] and rec.stop["step"] == "track force"
    assert rec.counts() == {"/loadcell/force": 1}


def test_an_exception_is_a_failure(logs):
    with pytest.raises(ZeroDivisionError):
        with Run("identify", progress=False) as run:
            1 / 0
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["status"] == "failed" and saved["error"] == "ZeroDivisionError: division by zero"
    assert read_recording(run.dir / "run.mcap").stop["status"] == "failed"


def test_a_failing_hold_never_masks_the_error_nor_spares_other_arms(logs):
    bad = FakeArm("PSM1", fail=RuntimeError("servo amplifier off"))
    good = FakeArm("PSM2")
    err = io.StringIO()
    with pytest.raises(AbortRun, match="stale measured_js"):
        with Run("cooperative", stream=err) as run:
            run.claim(bad)
            run.claim(good)
            raise AbortRun("stale measured_js on PSM1 (no sample for 80 ms)")
    assert good.holds == 1 and bad.holds == 1
    saved = json.loads((run.dir / "result.json").read_text())
    assert saved["hold_errors"] == [{"arm": "PSM1", "error": "RuntimeError: servo amplifier off"}]
    assert saved["held"] == ["PSM2"]
    assert "could not hold PSM1: RuntimeError: servo amplifier off" in err.getvalue()


def test_sigterm_becomes_an_abort_and_the_old_handler_comes_back(logs):
    before = signal.getsignal(signal.SIGTERM)
    arm = FakeArm("PSM1")
    with pytest.raises(AbortRun, match="SIGTERM"):
        with Run("identify", progress=False) as run:
            run.claim(arm)
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # Python runs the handler between bytecodes, raising here
                pass
            pytest.fail("SIGTERM did not stop the run")
    assert arm.holds == 1
    assert signal.getsignal(signal.SIGTERM) is before
    assert json.loads((run.dir / "result.json").read_text())["status"] == "aborted"


def test_a_signal_during_the_safe_stop_waits_for_it(logs):
    # A second Ctrl-C while the arms are being held must not cut the recording short.
    arm = FakeArm("PSM1", on_hold=lambda: os.kill(os.getpid(), signal.SIGINT))
    err = io.StringIO()
    with pytest.raises(AbortRun):
        with Run("identify", stream=err) as run:
            run.claim(arm)
            raise AbortRun("limit")
    assert "SIGINT while making the arms safe" in err.getvalue()
    assert read_recording(run.dir / "run.mcap").stop["status"] == "aborted"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def _start_target(logs: Path, mode: str, marker: Path) -> subprocess.Popen:
    env = dict(os.environ, RIG_LOGS=str(logs), PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, str(TARGET), mode, str(marker)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _check_killed_run(run_dir: Path, status: str, reason: str, marker: Path, min_samples: int):
    with open(run_dir / "run.mcap", "rb") as f:  # valid: the summary section is readable
        summary = make_reader(f).get_summary()
    assert summary is not None
    rec = read_recording(run_dir / "run.mcap")
    assert rec.finalised and rec.problem == ""
    assert rec.stop["status"] == status and reason in rec.stop["error"]
    assert rec.stop["held"] == ["PSM1", "PSM2"]
    js = rec.messages["/PSM1/measured_js"]
    assert len(js) >= min_samples
    assert rec.stop["counts"]["/PSM1/measured_js"] == len(js) == summary.statistics.channel_message_counts[
        next(c.id for c in summary.channels.values() if c.topic == "/PSM1/measured_js")]
    assert [m.effort[0] for _, m in js] == [float(i) for i in range(len(js))]  # none lost, in order
    assert rec.start["parameters"]["rate"]["value"] == 1000.0
    saved = json.loads((run_dir / "result.json").read_text())
    assert saved["status"] == status and reason in saved["error"]
    assert (marker / "held-PSM1").exists() and (marker / "held-PSM2").exists()


@pytest.mark.parametrize("sig, code, reason", [
    (signal.SIGINT, 130, "interrupted (Ctrl-C)"),
    (signal.SIGTERM, 3, "SIGTERM received"),
])
def test_killing_a_recording_process_finalises_its_run(tmp_path, sig, code, reason):
    logs, marker = tmp_path / "logs", tmp_path / "marker"
    marker.mkdir()
    proc = _start_target(logs, "wait", marker)
    try:
        line = proc.stdout.readline()
        assert line.startswith("READY "), proc.stderr.read() if proc.poll() is not None else line
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=120)  # a guard against a hang, not a figure
    finally:
        proc.kill()
    assert proc.returncode == code, stderr
    run_dir = Path(line.split(" ", 1)[1].strip())
    lines = [s for s in stderr.splitlines() if s.strip()]
    assert lines == [f"rig killtarget: aborted: {reason}" + (" (the process was asked to stop)" if sig == signal.SIGTERM else "")
                     + f" (run folder {run_dir})"]
    _check_killed_run(run_dir, "aborted", reason, marker, min_samples=500)


def test_an_exception_in_a_recording_process_finalises_its_run(tmp_path):
    logs, marker = tmp_path / "logs", tmp_path / "marker"
    marker.mkdir()
    proc = _start_target(logs, "raise", marker)
    _, stderr = proc.communicate(timeout=120)  # a guard against a hang, not a figure
    assert proc.returncode == 1
    assert "RuntimeError: simulated driver fault" in stderr  # a bug keeps its traceback
    _check_killed_run(_only_run(logs), "failed", "RuntimeError: simulated driver fault", marker, 500)


@click.command("demo")
@click.option("--limit", is_flag=True)
@json_option
@exit_on_abort
def demo(limit, as_json):
    with Run("demo", progress=False) as run:
        if limit:
            raise AbortRun("joint 2 velocity 1.9 rad/s above limit 1.5 rad/s")
        run.finish({"summary": {"rms": 0.5}})
    emit_result(run.result, as_json)


def test_json_goes_to_stdout_and_the_report_to_stderr(logs):
    result = CliRunner().invoke(demo, ["--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["status"] == "completed" and doc["summary"] == {"rms": 0.5}
    assert "rms: 0.5" in result.stderr and "rms" not in result.stdout.replace('"rms"', "")
    plain = CliRunner().invoke(demo, [])
    assert "demo: completed" in plain.stdout and "rms: 0.5" in plain.stdout


def test_an_abort_is_one_clear_line_and_a_non_zero_exit(logs):
    result = CliRunner().invoke(demo, ["--limit", "--json"])
    assert result.exit_code == 3
    # --json: the result document, status and reason included, is still the whole stdout
    doc = json.loads(result.stdout)
    assert doc["status"] == "aborted" and doc["error"] == "joint 2 velocity 1.9 rad/s above limit 1.5 rad/s"
    assert result.stderr.startswith("rig demo: aborted: joint 2 velocity 1.9 rad/s above limit 1.5 rad/s (run folder ")
    assert result.stderr.count("\n") == 1


def test_runs_started_in_the_same_microsecond_get_their_own_folders(logs, monkeypatch):
    import rig.runs.run as engine
    from datetime import datetime, timezone

    frozen = datetime(2026, 11, 21, 5, 2, 3, 999999, tzinfo=timezone.utc)

    class Frozen(datetime):
        @classmethod
        def now(cls, tz=None):
            return frozen

    monkeypatch.setattr(engine, "datetime", Frozen)
    with Run("selftest", progress=False) as first:
        pass
    with Run("selftest", progress=False) as second:
        pass
    assert first.dir.name == "20261121T050203999999Z-selftest"
    assert second.dir.name == "20261121T050204000000Z-selftest"


def test_a_run_whose_process_is_killed_outright_reads_back_and_lists_as_interrupted(tmp_path, monkeypatch):
    """SIGKILL leaves no chance to close anything: the recording is readable up to its last
    chunk on disk, in order, with no stop record, and `rig runs` shows the run interrupted
    (its owner file names a process that is gone), not running and not missing."""
    from click.testing import CliRunner

    from rig.cli import main
    from rig.runs.run_owner import OWNER_FILE

    logs, marker = tmp_path / "logs", tmp_path / "marker"
    marker.mkdir()
    proc = _start_target(logs, "wait", marker)
    try:
        line = proc.stdout.readline()
        assert line.startswith("READY "), proc.stderr.read() if proc.poll() is not None else line
        run_dir = Path(line.split(" ", 1)[1].strip())
        assert (run_dir / OWNER_FILE).exists()
        monkeypatch.setenv("RIG_LOGS", str(logs))
        listed = json.loads(CliRunner().invoke(main, ["runs", "--json"]).stdout)["runs"]
        assert [r["status"] for r in listed] == ["running"], listed
        mcap = run_dir / "run.mcap"
        deadline = time.monotonic() + 120.0  # a guard against a hang, not a figure
        while mcap.stat().st_size < 700 * 1024:  # more than one 512 kB chunk written
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    rec = read_recording(mcap)
    assert not rec.finalised and rec.stop is None and rec.problem
    js = rec.messages["/PSM1/measured_js"]
    assert len(js) >= 1000
    assert [m.effort[0] for _, m in js] == [float(i) for i in range(len(js))]  # from the first, in order
    assert not (marker / "held-PSM1").exists()  # nothing ran after the kill
    listed = json.loads(CliRunner().invoke(main, ["runs", "--json"]).stdout)["runs"]
    assert [r["status"] for r in listed] == ["interrupted"], listed
    assert listed[0]["error"].startswith("interrupted (no stop record)")
    text = CliRunner().invoke(main, ["runs"]).stdout
    assert "interrupted" in text and "no stop record" in text, text
