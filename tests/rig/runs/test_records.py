"""The recorder: ROS 2 encoding, channels, metadata, no loss, damaged files."""

import itertools
import math
import random
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

from rig.runs import ros_messages as rm
from rig.runs.recording import Recorder, RecorderError, quat_xyzw_from_matrix, read_recording


def _ros2_encoders():
    return {name: serialize_dynamic(name, text)[name] for name, text in rm.DEFINITIONS.items()}


def _header(t_ns, frame_id):
    return {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": frame_id}


def test_encoders_are_byte_identical_to_mcap_ros2():
    enc = _ros2_encoders()
    rnd = random.Random(3)
    frames = ["", "a", "ab", "abc", "abcd", "PSM1_base", "world"]
    name_sets = [(), ("j",), ("outer_yaw", "outer_pitch", "outer_insertion"), tuple("abcdefg")]
    lengths = [(0, 0, 0), (3, 3, 3), (7, 7, 7), (3, 0, 3), (0, 2, 0), (1, 2, 3)]
    for frame, names, (a, b, c) in itertools.product(frames, name_sets, lengths):
        pos, vel, eff = ([rnd.uniform(-2, 2) for _ in range(n)] for n in (a, b, c))
        t = rnd.randrange(0, 10**13)
        ours = rm.encode_joint_state(t, frame, names, pos, vel, eff)
        ref = enc[rm.JOINT_STATE]({"header": _header(t, frame), "name": list(names),
                                   "position": pos, "velocity": vel, "effort": eff})
        assert ours == ref, (frame, names, (a, b, c))
    for frame in frames:
        t = rnd.randrange(0, 10**13)
        p, q = [0.1, -0.2, 0.3], [0.0, 0.6, 0.0, 0.8]
        assert rm.encode_pose_stamped(t, frame, p, q) == enc[rm.POSE_STAMPED](
            {"header": _header(t, frame), "pose": {"position": dict(zip("xyz", p)),
                                                    "orientation": dict(zip("xyzw", q))}})
        f, tq = [1.5, 0.0, -2.0], [0.01, 0.02, 0.03]
        assert rm.encode_wrench_stamped(t, frame, f, tq) == enc[rm.WRENCH_STAMPED](
            {"header": _header(t, frame), "wrench": {"force": dict(zip("xyz", f)),
                                                      "torque": dict(zip("xyz", tq))}})
    assert rm.encode_float64(-3.25) == enc[rm.FLOAT64]({"data": -3.25})
    assert rm.encode_twist([1, 2, 3], [4, 5, 6]) == enc[rm.TWIST](
        {"linear": {"x": 1, "y": 2, "z": 3}, "angular": {"x": 4, "y": 5, "z": 6}})


def _fields(text: str) -> list[tuple[str, str]]:
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            ftype, name = line.split()[:2]
            out.append((ftype.split("/")[-1], name))
    return out


def test_definitions_match_the_installed_ros2_interfaces():
    share = Path(sys.prefix) / "share"
    # ros-jazzy-sensor-msgs is a declared dependency: its interface files missing is a broken install
    assert (share / "sensor_msgs" / "msg" / "JointState.msg").exists(), f"no ROS 2 interface files under {share}"
    for schema, text in rm.DEFINITIONS.items():
        sections = re.split(r"^={80}\nMSG: (\S+)\n", text, flags=re.MULTILINE)
        named = [(schema, sections[0])] + list(zip(sections[1::2], sections[2::2]))
        assert len(sections) % 2 == 1
        for name, body in named:
            pkg, *_, msg = name.split("/")
            installed = (share / pkg / "msg" / f"{msg}.msg").read_text()
            assert _fields(body) == _fields(installed), name
        if schema == rm.POSE_STAMPED:  # every nested type is defined, as ros2 bag writes it
            assert sections[1::2] == ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose",
                                      "geometry_msgs/Point", "geometry_msgs/Quaternion"]
    assert "MSG: std_msgs/Header" in rm.DEFINITIONS[rm.JOINT_STATE]
    assert "MSG: builtin_interfaces/Time" in rm.DEFINITIONS[rm.POSE_STAMPED]
    assert rm.DEFINITIONS[rm.WRENCH_STAMPED].count("=" * 80) == 4


def _record_sample_run(path: Path) -> dict:
    rec = Recorder(path)
    rec.start("unit", parameters={"rate": {"value": 1000.0, "units": "Hz"}},
              config={"arms": ["PSM1"]}, seed=42)
    q = np.zeros(3)
    for i in range(200):
        t = 1.0 + i * 1e-3
        q[:] = (t, -t, 0.1 * t)  # the same array, changed after each call: samples are snapshots
        rec.joint_state("/PSM1/measured_js", t, q, q * 2, q * 3, ("j1", "j2", "j3"), "PSM1_base")
        if i % 2 == 0:
            rec.tension("/loadcell/force", t, 0.25 * i)
        if i % 10 == 0:
            rec.pose("/mocap/tool/pose", t, (0.1, 0.2, 0.3 + i), (0.0, 0.0, 0.6, 0.8), "mocap")
            rec.joint_state("/PSM1/servo_jf", t, effort=[0.5, 0.0, -1.0])
            rec.scalar("/PSM1/gain", t, 2.5)
            rec.twist("/PSM1/measured_cv", t, (1, 2, 3), (4, 5, 6))
    return rec.close("completed")


def test_round_trip_through_the_public_mcap_reader(tmp_path):
    path = tmp_path / "run.mcap"
    stop = _record_sample_run(path)
    expected = {"/PSM1/measured_js": 200, "/loadcell/force": 100, "/mocap/tool/pose": 20,
                "/PSM1/servo_jf": 20, "/PSM1/gain": 20, "/PSM1/measured_cv": 20}
    assert stop["counts"] == expected
    assert stop["overflow"]["events"] == 0

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == sum(expected.values())
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert schemas["/PSM1/measured_js"].name == "sensor_msgs/msg/JointState"
        assert schemas["/loadcell/force"].name == "geometry_msgs/msg/WrenchStamped"
        assert schemas["/mocap/tool/pose"].name == "geometry_msgs/msg/PoseStamped"
        assert schemas["/PSM1/gain"].name == "std_msgs/msg/Float64"
        assert schemas["/PSM1/measured_cv"].name == "geometry_msgs/msg/Twist"
        assert {s.encoding for s in schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        js = [(m.log_time, m.publish_time, d) for _, _, m, d in
              reader.iter_decoded_messages(topics=["/PSM1/measured_js"])]
        force = [d for _, _, _, d in reader.iter_decoded_messages(topics=["/loadcell/force"])]
        pose = [d for _, _, _, d in reader.iter_decoded_messages(topics=["/mocap/tool/pose"])]
        jf = [d for _, _, _, d in reader.iter_decoded_messages(topics=["/PSM1/servo_jf"])]
        meta = {m.name: m.metadata for m in reader.iter_metadata()}

    assert len(js) == 200
    for i, (log_time, publish_time, msg) in enumerate(js):
        t_ns = 1_000_000_000 + i * 1_000_000
        t = t_ns * 1e-9
        assert log_time == publish_time == t_ns
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, i * 1_000_000)
        assert msg.header.frame_id == "PSM1_base"
        assert msg.name == ["j1", "j2", "j3"]
        assert msg.position == pytest.approx([t, -t, 0.1 * t], abs=1e-12)
        assert msg.effort == pytest.approx([3 * t, -3 * t, 0.3 * t], abs=1e-12)
    assert [f.wrench.force.x for f in force] == [0.25 * i for i in range(0, 200, 2)]
    assert all(f.wrench.force.y == 0 and f.header.frame_id == "loadcell" for f in force)
    assert pose[3].pose.position.z == pytest.approx(30.3)
    assert (pose[3].pose.orientation.z, pose[3].pose.orientation.w) == (0.6, 0.8)
    assert jf[0].position == [] and jf[0].effort == [0.5, 0.0, -1.0]

    assert meta["run_start"]["procedure"] == "unit"
    assert meta["run_start"]["seed"] == "42"
    assert '"units": "Hz"' in meta["run_start"]["parameters"]
    assert "package_version" in meta["run_start"] and "git_revision" in meta["run_start"]
    assert meta["run_stop"]["status"] == "completed"


def test_read_recording_decodes_metadata(tmp_path):
    path = tmp_path / "run.mcap"
    _record_sample_run(path)
    rec = read_recording(path)
    assert rec.finalised and rec.problem == ""
    assert rec.start["parameters"] == {"rate": {"value": 1000.0, "units": "Hz"}}
    assert rec.start["config"] == {"arms": ["PSM1"]} and rec.start["seed"] == 42
    assert rec.stop["counts"]["/PSM1/measured_js"] == 200
    assert rec.counts() == rec.stop["counts"]


def test_a_full_queue_makes_the_caller_wait_and_loses_nothing(tmp_path):
    rec = Recorder(tmp_path / "run.mcap", queue_limit=16)
    rec.start("unit")
    n = 5000
    for i in range(n):
        rec.joint_state("/PSM1/measured_js", i * 1e-3, [float(i)] * 7, [0.0] * 7, [0.0] * 7)
    stop = rec.close()
    assert stop["overflow"]["events"] > 0
    assert stop["counts"] == {"/PSM1/measured_js": n}
    values = [m.position[0] for _, m in read_recording(tmp_path / "run.mcap").messages["/PSM1/measured_js"]]
    assert values == [float(i) for i in range(n)]


def test_bad_samples_are_refused_in_the_caller(tmp_path):
    rec = Recorder(tmp_path / "run.mcap")
    with pytest.raises(ValueError, match="finite"):
        rec.scalar("/x", math.nan, 1.0)
    with pytest.raises(ValueError, match=">= 0"):
        rec.scalar("/x", -1.0, 1.0)
    with pytest.raises(ValueError, match="expected 4"):
        rec.pose("/mocap/a/pose", 0.0, (0, 0, 0), (0, 0, 1))
    with pytest.raises(ValueError, match="start with '/'"):
        rec.scalar("x", 0.0, 1.0)
    rec.scalar("/x", 0.0, 1.0)
    with pytest.raises(RecorderError, match="carries std_msgs/msg/Float64"):
        rec.tension("/x", 0.0, 1.0)
    stop = rec.close()
    assert stop["counts"] == {"/x": 1}
    with pytest.raises(RecorderError, match="closed"):
        rec.scalar("/x", 1.0, 1.0)
    with pytest.raises(FileExistsError):
        Recorder(tmp_path / "run.mcap")  # never overwrite a recording


def test_a_writer_failure_reaches_the_caller(tmp_path):
    rec = Recorder(tmp_path / "run.mcap")

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    rec._writer.add_message = broken
    rec.scalar("/x", 0.0, 1.0)
    rec._thread.join(timeout=2.0)  # the writer thread stops on its error
    with pytest.raises(RecorderError, match="No space left"):
        rec.scalar("/x", 0.001, 1.0)
    with pytest.raises(RecorderError, match="No space left"):
        rec.close("failed", "disk full")


def test_a_cut_file_gives_back_what_precedes_the_cut(tmp_path):
    path = tmp_path / "run.mcap"
    rec = Recorder(path, chunk_size=4096)
    rec.start("unit")
    for i in range(3000):
        rec.joint_state("/PSM1/measured_js", i * 1e-3, [float(i)] * 3)
    rec.close()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    rec = read_recording(cut)
    assert not rec.finalised and "ends early" in rec.problem
    positions = [m.position[0] for _, m in rec.messages["/PSM1/measured_js"]]
    assert 500 < len(positions) < 3000
    assert positions == [float(i) for i in range(len(positions))]  # a prefix, in order
    assert rec.start["procedure"] == "unit" and rec.stop is None


def _matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_quaternion_from_rotation_matrix():
    rng = np.random.default_rng(0)
    quats = [rng.normal(size=4) for _ in range(200)]
    # near-180-degree turns about each axis: the cases a single formula gets wrong
    quats += [np.array([1.0, 1e-9, 0, 1e-7]), np.array([0, 1.0, 0, 1e-8]), np.array([0, 0, 1.0, 0.0])]
    for q in quats:
        q = q / np.linalg.norm(q)
        q = q if q[3] >= 0 else -q
        assert np.allclose(quat_xyzw_from_matrix(_matrix(q)), q, atol=1e-9)
    assert quat_xyzw_from_matrix(np.eye(3)) == (0.0, 0.0, 0.0, 1.0)


def test_recording_the_device_dataclasses(tmp_path):
    from drivers.interfaces import ForceSample, JointState, Pose

    rec = Recorder(tmp_path / "run.mcap")
    rec.joint_state_sample("/PSM1/measured_js", JointState(0.5, np.array([1.0, 2.0, 0.1]),
                                                           np.zeros(3), np.ones(3), ("a", "b", "c")))
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    rec.pose_sample("/mocap/base/pose", Pose(0.5, np.array([0.0, 0.1, 0.2]), turn, "mocap"))
    rec.force_sample("/loadcell/force", ForceSample(0.5, 3.5, raw=123, seq=4))
    rec.close()
    msgs = read_recording(tmp_path / "run.mcap").messages
    js = msgs["/PSM1/measured_js"][0][1]
    assert js.name == ["a", "b", "c"] and js.position == [1.0, 2.0, 0.1] and js.effort == [1.0] * 3
    o = msgs["/mocap/base/pose"][0][1].pose.orientation
    assert (o.x, o.y) == (0.0, 0.0) and o.z == pytest.approx(math.sqrt(0.5)) and o.w == pytest.approx(math.sqrt(0.5))
    assert msgs["/loadcell/force"][0][1].wrench.force.x == 3.5


def test_a_process_that_exits_without_close_still_leaves_a_finished_file(tmp_path):
    import subprocess

    path = tmp_path / "run.mcap"
    script = ("import sys; from rig.runs.recording import Recorder\n"
              f"r = Recorder({str(path)!r}); r.start('unit')\n"
              "for i in range(300): r.scalar('/x', i * 1e-3, float(i))\n"
              "sys.exit(0)\n")
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)  # a guard against a hang
    rec = read_recording(path)
    assert rec.finalised and rec.counts() == {"/x": 300}
    assert rec.stop["status"] == "failed"
    assert rec.stop["error"] == "process exited without closing the recording"
