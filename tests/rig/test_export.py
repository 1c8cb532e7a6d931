"""`rig export`: every recorded stream of a real (simulated) run, by topic, as CSV with a
header and a time column in seconds; anything else refused in one line."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner
from mcap_ros2.writer import Writer as Ros2Writer

from rig.cli import main
from rig.runs.recording import read_recording
from tests.rig.cooperative_runs import SHORT, cooperative_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """(run folder, result) of a short completed cooperative run."""
    run_dir, result, report = cooperative_run(tmp_path_factory.mktemp("coop"), SHORT)
    assert result["status"] in ("completed", "failed"), result.get("error")
    # the report and the result carry the Cartesian tracking, the figures are drawn
    assert "Cartesian tracking, tool tip against its plan (world frame), from the motion's start:" in report
    assert "PSM1 (slave): RMS" in report and "PSM2 (master): RMS" in report
    assert (run_dir / "cooperative.png").exists() and (run_dir / "cooperative-tracking.png").exists()
    assert result["tracking_plot"] == str(run_dir / "cooperative-tracking.png")
    return run_dir, result


def invoke(*args):
    res = CliRunner().invoke(main, ["export", *map(str, args)])
    assert "Traceback" not in res.output, res.output
    return res


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array([[float(x) if x else np.nan for x in r] for r in rows[1:]])


def one_line(res) -> str:
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1, res.output
    return lines[0]


def test_every_topic_exports_with_a_header_and_a_time_column(run, tmp_path):
    run_dir, result = run
    res = invoke(run_dir, "--out", tmp_path / "csv")
    assert res.exit_code == 0, res.output
    rec = read_recording(run_dir / "run.mcap")
    files = {p.name for p in (tmp_path / "csv").iterdir()}
    for topic in rec.schemas:  # every recorded stream, one file each
        assert topic.strip("/").replace("/", ".") + ".csv" in files, (topic, files)
    assert {"loadcell.force.csv", "PSM1.measured_cp.csv", "PSM1.setpoint_cp.csv", "PSM2.measured_cp.csv",
            "cooperative.force_setpoint.csv", "PSM1.measured_js.csv"} <= files

    header, table = read_csv(tmp_path / "csv" / "loadcell.force.csv")
    assert header == ["t", "force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z"]
    samples = rec.messages["/loadcell/force"]
    assert len(table) == len(samples) == rec.stop["counts"]["/loadcell/force"]
    stamps = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in samples])
    np.testing.assert_allclose(table[:, 0], np.sort(stamps), atol=1e-9)  # seconds on the run clock
    assert np.all(np.diff(table[:, 0]) >= 0) and 0.0 <= table[0, 0] < table[-1, 0] < 10.0
    np.testing.assert_array_equal(table[:, 1], [m.wrench.force.x for _, m in samples])  # the tension, exact

    header, setpoint = read_csv(tmp_path / "csv" / "cooperative.force_setpoint.csv")
    assert header == ["t", "data"]
    assert setpoint[-1, 1] == pytest.approx(3.0)

    header, joints = read_csv(tmp_path / "csv" / "PSM1.measured_js.csv")
    assert header == ["t"] + [f"{q}_{j}" for q in ("position", "velocity", "effort") for j in (1, 2, 3)]


def test_tips_measured_and_planned_export_and_give_the_reported_tracking(run, tmp_path):
    run_dir, result = run
    for arm in ("PSM1", "PSM2"):
        for kind in ("measured_cp", "setpoint_cp"):
            res = invoke(run_dir, "--out", tmp_path, "--topic", f"/{arm}/{kind}")
            assert res.exit_code == 0, res.output
    header, measured = read_csv(tmp_path / "PSM1.measured_cp.csv")
    assert header == ["t", "position_x", "position_y", "position_z",
                      "orientation_x", "orientation_y", "orientation_z", "orientation_w"]
    _, planned = read_csv(tmp_path / "PSM1.setpoint_cp.csv")
    assert len(measured) == len(planned) == 2300  # one per control tick
    # the slave's largest tip error from the motion's start, as the result reports it
    rec = read_recording(run_dir / "run.mcap", topics=[])
    loop = rec.metadata["cooperative_loop"]
    moving = planned[:, 0] >= float(loop["motion_start"]) - 1e-9
    error_mm = 1e3 * np.linalg.norm(measured[moving, 1:4] - planned[moving, 1:4], axis=1)
    tracking = result["cartesian_tracking"]["arms"]
    assert tracking["PSM1"]["role"] == "slave" and tracking["PSM2"]["role"] == "master"
    assert tracking["PSM1"]["max_mm"] == pytest.approx(error_mm.max(), rel=1e-9)
    assert tracking["PSM1"]["rms_mm"] == pytest.approx(np.sqrt(np.mean(error_mm ** 2)), rel=1e-9)


def test_a_named_topic_only_and_an_unknown_one_refused_in_one_line(run, tmp_path):
    run_dir, _ = run
    res = invoke(run_dir, "--out", tmp_path / "one", "--topic", "/loadcell/force")
    assert res.exit_code == 0, res.output
    assert [p.name for p in (tmp_path / "one").iterdir()] == ["loadcell.force.csv"]
    res = invoke(run_dir, "--out", tmp_path / "two", "--topic", "/loadcell/tension")
    assert res.exit_code == 5
    line = one_line(res)
    assert "no topic /loadcell/tension in" in line and "/loadcell/force" in line
    assert not (tmp_path / "two").exists()


def test_the_wpi_psm_csv_is_unchanged_and_refuses_a_wrench_in_one_line(run, tmp_path):
    run_dir, _ = run
    res = invoke(run_dir, "--csv", tmp_path / "psm1.csv", "--rate", "100")
    assert res.exit_code == 0, res.output
    assert "joints, q|dq|tau) at 100 Hz" in res.output
    table = np.loadtxt(tmp_path / "psm1.csv", delimiter=",")
    assert table.shape[1] == 9 and 220 <= len(table) <= 231
    res = invoke(run_dir, "--csv", tmp_path / "f.csv", "--topic", "/loadcell/force")
    assert res.exit_code == 5
    line = one_line(res)
    assert "WrenchStamped, not a JointState" in line and "--out DIR --topic /loadcell/force" in line
    res = invoke(run_dir, "--out", tmp_path / "x", "--rate", "100")
    assert res.exit_code == 2 and "--rate resamples the --csv joint table" in res.output


def test_list_names_every_topic_with_its_type_and_count(run):
    run_dir, _ = run
    res = invoke(run_dir, "--list")
    assert res.exit_code == 0, res.output
    line = next(ln for ln in res.output.splitlines() if ln.startswith("/PSM1/measured_cp "))
    assert line.split()[1:] == ["2300", "geometry_msgs/msg/PoseStamped"]


def test_types_the_recorder_does_not_write_export_or_are_refused(tmp_path):
    run_dir = tmp_path / "logs" / "20260101T000000000000Z-other"
    run_dir.mkdir(parents=True)
    with open(run_dir / "run.mcap", "wb") as f:
        w = Ros2Writer(f)
        array = w.register_msgdef("std_msgs/msg/Float64MultiArray",
                                  "MultiArrayLayout layout\nfloat64[] data\n"
                                  "================================================================================\n"
                                  "MSG: std_msgs/MultiArrayLayout\nMultiArrayDimension[] dim\nuint32 data_offset\n"
                                  "================================================================================\n"
                                  "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n")
        text = w.register_msgdef("std_msgs/msg/String", "string data\n")
        for i in range(5):
            w.write_message("/gains", array, {"layout": {"dim": [], "data_offset": 0},
                                              "data": [float(i), 2.0 * i, 0.5]}, log_time=i * 10_000_000)
            w.write_message("/note", text, {"data": f"sample {i}"}, log_time=i * 10_000_000)
        w.finish()
    res = invoke(run_dir, "--out", tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert "warning: skipped: /note carries std_msgs/msg/String, which has no numeric fields to export" in res.output
    header, table = read_csv(tmp_path / "out" / "gains.csv")
    assert header == ["t", "layout_data_offset", "data_1", "data_2", "data_3"]
    np.testing.assert_allclose(table[:, 0], np.arange(5) * 0.01)  # no header: the log time, s
    np.testing.assert_allclose(table[:, 3], 2.0 * np.arange(5))
    res = invoke(run_dir, "--out", tmp_path / "out", "--topic", "/note")
    assert res.exit_code == 5
    assert "/note carries std_msgs/msg/String, which has no numeric fields" in one_line(res)


def test_the_cooperative_run_records_tips_set_point_and_its_loop(run):
    run_dir, result = run
    rec = read_recording(run_dir / "run.mcap")
    counts = rec.stop["counts"]
    for arm in ("PSM1", "PSM2"):
        assert counts[f"/{arm}/measured_cp"] == counts[f"/{arm}/setpoint_cp"] == counts[f"/{arm}/measured_js"] == 2300
    assert counts["/cooperative/force_setpoint"] == 2300
    _, pose = rec.messages["/PSM2/measured_cp"][0]
    assert pose.header.frame_id == "world"
    loop = rec.metadata["cooperative_loop"]
    assert loop["master"] == "PSM2" and loop["arms"] == "PSM1,PSM2"
    assert float(loop["motion_end"]) - float(loop["motion_start"]) == pytest.approx(1.0)
