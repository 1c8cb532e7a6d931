"""`rig plot RUN`: a run's figures drawn again from its recording, for a completed, an
aborted and a cut (killed) cooperative run and for any other procedure."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from click.testing import CliRunner

from procedures import cooperative_figures as cf
from rig.cli import main
from rig.runs.recording import read_recording
from rig.runs.run import Run
from tests.rig.cooperative_runs import ABORTING, SHORT, cooperative_run

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coop")
    completed, result, _ = cooperative_run(folder, SHORT)
    time.sleep(0.002)
    aborted, aborted_result, stderr = cooperative_run(folder, ABORTING)
    assert aborted_result["status"] == "aborted", aborted_result
    assert f"rig plot {aborted}" in stderr  # the abort says how to see its figures
    return {"completed": (completed, result), "aborted": (aborted, aborted_result)}


def plot(*args):
    res = CliRunner().invoke(main, ["plot", *map(str, args)])
    assert "Traceback" not in res.output, res.output
    return res


def pngs(folder):
    found = {p.name: p for p in folder.iterdir() if p.suffix == ".png"}
    for p in found.values():
        assert p.read_bytes()[:8] == PNG and p.stat().st_size > 10_000, p
    return found


def test_a_completed_run_gets_its_figures_and_every_stream(runs, tmp_path):
    run_dir, result = runs["completed"]
    res = plot(run_dir, "--out", tmp_path / "figs")
    assert res.exit_code == 0, res.output
    names = set(pngs(tmp_path / "figs"))
    assert {"cooperative.png", "cooperative-tracking.png", "plot-PSM1-joints.png", "plot-PSM2-joints.png",
            "plot-PSM1-poses-world.png", "plot-forces.png", "plot-signals.png"} <= names
    # the numbers drawn from the recording are the run's own
    slave = result["cartesian_tracking"]["arms"]["PSM1"]
    assert f"PSM1 (slave): RMS {slave['rms_mm']:.2f} mm, max {slave['max_mm']:.2f} mm" in res.output
    assert "(completed)" in res.output or "(failed)" in res.output


def test_an_aborted_run_is_drawn_up_to_where_it_stopped(runs):
    run_dir, result = runs["aborted"]
    assert not (run_dir / "cooperative.png").exists()  # the run itself drew none
    res = plot(run_dir, "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout.strip().splitlines()[-1])
    assert doc["status"] == "aborted"
    names = set(pngs(run_dir))
    assert {"cooperative.png", "cooperative-tracking.png", "plot-PSM1-joints.png", "plot-forces.png"} <= names
    trace = cf.trace_from_recording(read_recording(run_dir / "run.mcap"), "t")
    assert trace.stopped.startswith("aborted: tension") and "ceiling" in trace.stopped
    assert 0.0 < trace.t[-1] < 2.3 - 0.1  # cut short of the planned 2.3 s
    assert np.nanmax(trace.tension) > 3.02  # the tick that broke the ceiling is in the recording


def test_a_killed_run_with_a_cut_recording_is_drawn_from_what_it_holds(runs, tmp_path):
    run_dir, _ = runs["completed"]
    cut = tmp_path / "logs" / run_dir.name
    cut.mkdir(parents=True)
    data = (run_dir / "run.mcap").read_bytes()
    (cut / "run.mcap").write_bytes(data[: int(0.6 * len(data))])  # SIGKILL: no footer, no stop record
    res = plot(cut)
    assert res.exit_code == 0, res.output
    assert "(unfinished)" in res.output
    assert {"cooperative.png", "plot-forces.png"} <= set(pngs(cut))


def test_any_procedure_gets_time_series_of_its_streams(tmp_path):
    with Run("identify", progress=False) as run:
        for i in range(300):
            t = 1.0 + i / 1000.0
            q = [0.1 * t, -0.2 * t, 0.1 + 0.01 * t]
            run.recorder.joint_state("/PSM1/measured_js", t, q, q, q)
            run.recorder.joint_state("/PSM1/servo_jp", t, q, q)
        run.finish({"summary": {}})
    res = plot(run.dir.name)  # by name under $RIG_LOGS
    assert res.exit_code == 0, res.output
    assert set(pngs(run.dir)) == {"plot-PSM1-joints.png"}


def test_a_run_with_nothing_to_draw_and_a_missing_run_are_one_line(tmp_path):
    with Run("register", progress=False) as run:
        run.finish({})
    for res in (plot(run.dir), plot("no-such-run")):
        assert res.exit_code == 5
        assert len([ln for ln in res.output.splitlines() if ln.strip()]) == 1, res.output
    assert "holds no samples to draw" in plot(run.dir).output
