"""rig cooperative on the simulated rig: figures, modes and every safety trigger."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from rig import config
from rig.cli import main
from rig.runs.recording import read_recording


def _invoke(args):
    res = CliRunner().invoke(main, ["cooperative", *args, "--json"])
    lines = [line for line in res.stdout.strip().splitlines() if line.startswith("{")]
    data = json.loads(lines[-1]) if lines else None
    return res, data


def _run_dir_result(res_data):
    with open(os.path.join(res_data["run_dir"], "result.json")) as f:
        return json.load(f)


def test_holds_five_newtons_on_the_spring_while_moving():
    res, data = _invoke(["--force", "5", "--duration", "3", "--settle", "1.5", "--hold-after", "1"])
    assert res.exit_code == 0, res.output
    assert data["status"] == "completed"
    assert data["max_error_during_motion"] < 0.25
    assert data["overshoot"] < 0.5
    assert not data["limit_cycle"]
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"))
    assert rec.finalised and rec.stop["status"] == "completed"
    counts = rec.counts()
    assert counts["/PSM1/measured_js"] >= 5400 and counts["/loadcell/force"] >= 2700
    assert os.path.exists(data["plot"])


def test_dry_run_moves_nothing_and_checks_limits():
    res, data = _invoke(["--dry-run"])
    assert res.exit_code == 0, res.output
    assert data["status"] == "dry-run" and "recording_error" not in data
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"))
    assert rec.finalised and rec.stop["status"] == "dry-run"
    assert not any(t.endswith("servo_jp") or t.endswith("servo_jf") for t in rec.counts()), rec.counts()
    res, data = _invoke(["--dry-run", "--move", "0.6,0,0"])
    assert res.exit_code != 0
    assert "plan:" in res.output


@pytest.mark.parametrize("args, reason", [
    (["--force", "5", "--tension-ceiling", "5.05"], "above the ceiling 5.05 N"),
    (["--move", "0,0,-0.4"], "plan:"),
])
def test_limits_abort_hold_and_finalise(args, reason):
    res, _ = _invoke(args + ["--duration", "2", "--settle", "1.5"])
    assert res.exit_code != 0
    assert reason in res.output
    runs = sorted(p for p in os.listdir("logs"))
    result = json.load(open(os.path.join("logs", runs[-1], "result.json")))
    assert result["status"] == "aborted" and reason in result["error"]
    rec = read_recording(os.path.join("logs", runs[-1], "run.mcap"))
    assert rec.finalised and rec.stop["status"] == "aborted"


def _api_run(monkeypatch, patch):
    from procedures import cooperative as coop

    cfg = config.load()
    params = {"force": 5.0, "duration": 2.0, "settle": 1.0, "hold_after": 0.5, "deadband": 0.4,
              "tension_ceiling": 15.0}
    patch(monkeypatch)
    return coop.run(cfg, ["PSM1", "PSM2"], "PSM2", params, np.array([0.02, 0, 0]), np.zeros(3),
                    "impedance", progress=False)


def test_effort_ceiling_aborts_and_every_moved_arm_holds(monkeypatch):
    from rig.runs import safety
    from rig.runs.run import AbortRun

    held = []
    from drivers.arm import sim as sim_arm

    orig_hold = sim_arm.SimArm.hold

    def spy(self):
        held.append((self.name, self.world.mode(self.name)))
        return orig_hold(self)

    def patch(mp):
        mp.setattr(safety.SafetyLimits, "__init__", _limits_with(effort_limit=np.array([0.05, 5.0, 15.0])))
        mp.setattr(sim_arm.SimArm, "hold", spy)

    with pytest.raises(AbortRun, match="effort .* beyond its limit"):
        _api_run(monkeypatch, patch)
    assert {n for n, _ in held} == {"PSM1", "PSM2"}


def _limits_with(**overrides):
    from rig.runs import safety

    original = safety.SafetyLimits.__init__

    def init(self, *a, **k):
        original(self, *a, **k)
        for key, value in overrides.items():
            setattr(self, key, value)
    return init


def test_workspace_box_aborts_at_run_time(monkeypatch):
    from rig.runs import safety
    from rig.runs.run import AbortRun

    calls = {"n": 0}
    original = safety.SafetyLimits.check_arm

    def narrowing(self, name, q, dq, effort, tip):
        calls["n"] += 1
        if calls["n"] > 400:  # the box shrinks mid-run: the live check must catch it
            self.workspace_max = np.array([0.3, 0.35, 0.15])
        return original(self, name, q, dq, effort, tip)

    with pytest.raises(AbortRun, match="outside the workspace box"):
        _api_run(monkeypatch, lambda mp: mp.setattr(safety.SafetyLimits, "check_arm", narrowing))


def test_joint_velocity_limit_aborts(monkeypatch):
    from rig.runs import safety
    from rig.runs.run import AbortRun

    with pytest.raises(AbortRun, match="velocity .* above"):
        _api_run(monkeypatch, lambda mp: mp.setattr(safety.SafetyLimits, "__init__",
                                                    _limits_with(velocity_margin=1e-4)))


def test_stale_load_cell_aborts(monkeypatch):
    from drivers.loadcell import sim as loadcell_sim
    from rig.runs.run import AbortRun

    # the cell goes silent: after 300 of its sample instants it converts nothing more
    original = loadcell_sim.SimForceSensor._on_tick
    state = {"calls": 0}

    def dying(self, t):
        state["calls"] += 1
        if state["calls"] < 300:
            original(self, t)

    with pytest.raises(AbortRun, match="load cell stale"):
        _api_run(monkeypatch, lambda mp: mp.setattr(loadcell_sim.SimForceSensor, "_on_tick", dying))


def _held_up_reader(mp, start: int, length: int) -> None:
    """The load cell streams but its samples stop reaching the loop for `length` calls
    from call `start`, then arrive in one burst: the serial driver's reader thread held
    up on a loaded machine. Its stream age (as of the reader's last look) stays small, as
    the driver's does (drivers.loadcell: a starved reader is no silence of the cell)."""
    from drivers.loadcell import sim as loadcell_sim

    original = loadcell_sim.SimForceSensor.samples
    calls = {"n": 0}

    def samples(self):
        calls["n"] += 1
        return [] if start <= calls["n"] < start + length else original(self)

    mp.setattr(loadcell_sim.SimForceSensor, "samples", samples)
    mp.setattr(loadcell_sim.SimForceSensor, "stream_age", lambda self: 0.0)


def _api_run_serial_timeout(monkeypatch, patch):
    """_api_run with a serial cell's stale timeout (0.5 s) and the tension recorded."""
    from procedures import cooperative as coop

    cfg = config.load()
    cfg.loadcell["stale_timeout"] = 0.5
    params = {"force": 5.0, "duration": 2.0, "settle": 1.0, "hold_after": 0.5, "deadband": 0.4,
              "tension_ceiling": 15.0, "tolerance": 2.0}
    patch(monkeypatch)
    return coop.run(cfg, ["PSM1", "PSM2"], "PSM2", params, np.array([0.02, 0, 0]), np.zeros(3),
                    "impedance", progress=False)


def test_force_loop_holds_while_samples_do_not_reach_it(monkeypatch):
    # 0.3 s without a sample from the take-up on (the loop at 1 kHz): acting on the last
    # sample, the take-up kept stretching the spring blind and the burst that followed
    # drove joint 2's effort past its ceiling (the over-the-wire chain's abort under load)
    result = _api_run_serial_timeout(monkeypatch, lambda mp: _held_up_reader(mp, 5, 300))
    lt = result["loop_timing"]
    assert 295 <= lt["force_hold_longest_ms"] <= 310, lt
    rec = read_recording(os.path.join(result["run_dir"], "run.mcap"), ["/loadcell/force"])
    peak = max(m.wrench.force.x for _, m in rec.messages["/loadcell/force"])
    assert peak < 5.5, peak  # the tension was not wound up while unmeasured


def test_a_short_hold_up_while_moving_costs_the_triangle_little_tracking(monkeypatch):
    # three arms at 250 Hz (the over-the-wire default), 5 cm in 5 s: 40 ms without a
    # sample from any cell half-way through the motion. Holding the force loop: 0.09 N
    # while moving, as without the hold-up; coasting on the last samples: 0.22 N (0.53 N
    # with the joints read a tick late, and 100 ms then aborted on an effort ceiling)
    from procedures import cooperative as coop

    cfg = config.load(os.path.join(os.path.dirname(__file__), "..", "..", "examples", "three-arms.toml"))
    cfg.rig["rate"] = 250.0
    cfg.loadcell["stale_timeout"] = 0.5
    _held_up_reader(monkeypatch, 3 * 1125, 3 * 10)  # three cells, one call each per tick
    result = coop.run(cfg, ["PSM1", "PSM2", "PSM3"], "PSM3", dict(
        force=5.0, duration=5.0, settle=2.0, hold_after=0.5, deadband=0.4, tension_ceiling=15.0, tolerance=0.5),
        np.array([0.05, 0, 0]), np.zeros(3), "impedance", progress=False)
    assert 38 <= result["loop_timing"]["force_hold_longest_ms"] <= 48, result["loop_timing"]
    assert result["max_error_during_motion"] < 0.15, result["summary"]


def test_a_hold_on_the_first_tick_commands_what_the_starting_tension_does():
    # Over the wire the first tick often finds the newest sample older than two frames,
    # and holds. It must act on the tension measured at the start: with none (zero), the
    # impedance's measured-force term, scaled by the arm's Cartesian inertia over the
    # desired one, commanded 2.4 N m more on PSM1's joint 1 than its PID was applying
    # under a triangle's 1.9 N, and the triangle rang to the effort ceiling.
    from procedures.cooperative import build_controller
    from rig.model import psm_kinematics as K
    from rig.model.psm_dynamics import PSMDynamics

    cfg = config.load(os.path.join(os.path.dirname(__file__), "..", "..", "examples", "three-arms.toml"))
    names = ["PSM1", "PSM2", "PSM3"]
    frames = {n: cfg.base_matrix(n) @ K.RCM_FRAME for n in names}
    params = {"force": 5.0, "duration": 5.0, "settle": 2.0, "deadband": 0.4}
    q0 = {n: np.array(cfg.arms[n]["q0"], float) for n in names}
    tension = np.array([1.9, 1.9, 1.9])

    def first_command(**step) -> dict:
        c = build_controller(cfg, names, "PSM3", params, np.array([0.05, 0, 0]), np.zeros(3), "impedance",
                             PSMDynamics(), None, frames, "spring", 2450.0,
                             [("PSM1", "PSM2"), ("PSM1", "PSM3"), ("PSM2", "PSM3")], 0.004)
        c.start(0.0, q0, {n: np.zeros(3) for n in names}, tension)
        return c.step(0.004, q0, {n: np.zeros(3) for n in names}, **step)

    fresh = first_command(tension=tension)
    held = first_command(tension=None, blind=True)
    for arm in ("PSM1", "PSM2"):
        assert np.allclose(held[arm].effort, fresh[arm].effort, atol=1e-3), (arm, held[arm].effort,
                                                                           fresh[arm].effort)


def test_samples_not_reaching_the_loop_for_the_stale_timeout_abort_naming_the_load_cell(monkeypatch):
    from rig.runs.run import AbortRun

    with pytest.raises(AbortRun, match="load cell stale: no sample reached the control loop for 50[0-9] ms"):
        _api_run_serial_timeout(monkeypatch, lambda mp: _held_up_reader(mp, 5, 2000))


def test_stale_arm_stream_aborts(monkeypatch):
    from drivers.arm import sim as sim_arm
    from drivers.arm.crtk import StaleStream

    original = sim_arm.SimArm.measured_js
    state = {"calls": 0}

    def dying(self):
        state["calls"] += 1
        if state["calls"] > 800:
            raise StaleStream(f"/{self.name}/measured_js", 0.06, 0.05)
        return original(self)

    with pytest.raises(StaleStream):
        _api_run(monkeypatch, lambda mp: mp.setattr(sim_arm.SimArm, "measured_js", dying))
    runs = sorted(os.listdir("logs"))
    result = json.load(open(os.path.join("logs", runs[-1], "result.json")))
    assert result["status"] in ("failed", "aborted") and "measured_js" in result["error"]


def test_ctrl_c_holds_and_finalises(tmp_path):
    env = dict(os.environ, RIG_LOGS=str(tmp_path / "logs"))
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "cooperative", "--duration", "30"],
                            cwd=tmp_path, env=env, stderr=subprocess.PIPE, text=True)
    seen = ""
    deadline = time.time() + 60
    while "hold the tension while moving" not in seen and time.time() < deadline:
        seen += proc.stderr.readline()
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out = proc.communicate(timeout=60)[1]
    assert proc.returncode == 130
    assert "aborted" in out
    run = sorted((tmp_path / "logs").iterdir())[-1]
    result = json.loads((run / "result.json").read_text())
    assert result["status"] == "aborted"
    assert set(result["held"]) == {"PSM1", "PSM2"}
    rec = read_recording(run / "run.mcap")
    assert rec.finalised and rec.stop["status"] == "aborted"


def test_position_mode_limit_cycles_with_a_small_deadband_and_not_with_a_large_one():
    res, small = _invoke(["--mode", "position", "--deadband", "0.05", "--duration", "2", "--settle", "2",
                          "--hold-after", "2"])
    res2, large = _invoke(["--mode", "position", "--deadband", "0.4", "--duration", "2", "--settle", "2",
                           "--hold-after", "2"])
    assert small is not None and large is not None, res.output + res2.output
    assert small["limit_cycle"] and not large["limit_cycle"]


def test_three_arms_hold_every_element_near_the_set_point(tmp_path):
    (tmp_path / "rig.toml").write_text(
        '[arms.PSM1]\n[arms.PSM2]\nbase_xyz = [1.0728, 0.0, 0.0]\nbase_rpy = [0.0, 0.0, 3.14159265]\n'
        '[arms.PSM3]\nbase_xyz = [0.5364, 0.5730, 0.0]\nbase_rpy = [0.0, 0.0, -1.5707963]\n'
        '[object]\narms = ["PSM1", "PSM2", "PSM3"]\nrest_length = 0.099\n')
    res, data = _invoke(["--master", "PSM1", "--duration", "5", "--settle", "2", "--hold-after", "1"])
    assert res.exit_code == 0, res.output
    # the bounds hold on every element, the slave-slave one included
    assert max(data["element_rms_error"]) < 0.1
    assert data["max_error_during_motion"] < 0.25
    assert data["overshoot"] < 0.5
    assert not data["limit_cycle"]


def test_string_is_taken_up_without_overshoot(tmp_path):
    """A string at 20 kN/m starts slack: the slave takes it up at a set speed before the
    set-point ramps (integrating the error over the slack overshot by 2 N)."""
    (tmp_path / "rig.toml").write_text('[object]\nkind = "string"\nstiffness = 20000.0\n')
    res, data = _invoke(["--duration", "3", "--settle", "2",
                         "--hold-after", "1"])
    assert res.exit_code == 0, res.output
    assert data["overshoot"] < 0.5
    assert data["max_error_during_motion"] < 0.25
    assert data["rms_error"] < 0.1
    assert not data["limit_cycle"]


def test_user_increments_are_slewed_and_checked_against_their_targets():
    """A live increment is a target: the controller ramps its applied offset toward it at the
    slew rate (no step in one cycle), while a limit check of the plan sees the target."""
    from procedures.cooperative import build_controller
    from rig.model import psm_kinematics as K
    from rig.model.psm_dynamics import PSMDynamics

    cfg = config.load()
    names = ["PSM1", "PSM2"]
    frames = {n: cfg.base_matrix(n) @ K.RCM_FRAME for n in names}
    params = {"force": 5.0, "duration": 1.0, "settle": 0.5, "deadband": 0.4}
    c = build_controller(cfg, names, "PSM2", params, np.zeros(3), np.zeros(3), "impedance", PSMDynamics(), None,
                         frames, "spring", 2450.0, [("PSM1", "PSM2")], 1e-3)
    q = {n: np.array([0.0, 0.0, 0.12]) for n in names}   # the arms held still: only the offsets move
    zero = {n: np.zeros(3) for n in names}
    c.start(0.0, q, zero, np.array([5.0]))
    start = c.desired(0.0)[0]["PSM1"].copy()
    c.offset_translation = np.array([0.0, 0.01, 0.0])
    c.force_offset = 1.0
    assert c.desired(0.0, targets=True)[0]["PSM1"] == pytest.approx(start + [0, 0.01, 0])
    steps = []
    for k in range(1, 1201):
        c.step(k * 1e-3, q, zero, np.array([5.0]))
        steps.append(c.applied_translation[1])
    d = np.diff(np.concatenate([[0.0], steps]))
    assert d.max() == pytest.approx(c.slew_translation * 1e-3)     # 10 um per 1 ms cycle, no step
    assert steps[499] == pytest.approx(0.005)                        # half way after 0.5 s
    assert steps[-1] == pytest.approx(0.01)                          # there after 1 s
    assert c.applied_force_offset == pytest.approx(1.0)              # 1 N at 2 N/s: after 0.5 s
    assert c.desired(1.2)[0]["PSM1"] == pytest.approx(start + [0, 0.01, 0])


def test_rotate_turns_the_object_about_its_centroid_and_holds_the_tension():
    """--rotate (eq. 6.3): the tips turn about the object's centroid by the Euler angles
    while the tension is held; read back from the recording's measured joint states."""
    from rig.model import psm_kinematics as K

    res, data = _invoke(["--move", "0,0,0", "--rotate", "0,0,0.3", "--duration", "3", "--settle", "2",
                         "--hold-after", "1.5"])
    assert res.exit_code == 0, res.output
    assert data["max_error_during_motion"] < 0.25 and not data["limit_cycle"]
    cfg = config.load()
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"), topics=["/PSM1/measured_js", "/PSM2/measured_js"])
    tips = {}
    for n in ("PSM1", "PSM2"):
        msgs = rec.messages[f"/{n}/measured_js"]
        frame = cfg.base_matrix(n) @ K.RCM_FRAME
        first, last = (np.array(msgs[i][1].position[:3]) for i in (len(msgs) // 8, -1))
        tips[n] = [frame[:3, :3] @ K.tip_in_rcm(q) + frame[:3, 3] for q in (first, last)]
    before = tips["PSM1"][0] - tips["PSM2"][0]
    after = tips["PSM1"][1] - tips["PSM2"][1]
    turned = np.angle(np.exp(1j * (np.arctan2(after[1], after[0]) - np.arctan2(before[1], before[0]))))
    assert turned == pytest.approx(0.3, abs=0.01)
    centroid = [(tips["PSM1"][i] + tips["PSM2"][i]) / 2 for i in (0, 1)]
    # each tip travels 15 mm on its arc; the centroid stays within 10 % of that. It moved
    # 0.97 mm with the spring's desired inertia 0.5 kg and 1.00 mm with 1 kg, mostly a
    # 0.85 mm sag: the slave's impedance (400 N/m) against the model's error, not the turn.
    assert np.linalg.norm(centroid[1] - centroid[0]) < 1.5e-3


def test_uses_the_registration_run_and_the_model_file_and_says_which(tmp_path):
    """After `rig register` the arms' RCM frames come from that run, and --model FILE is
    the controllers' model; the result names both."""
    from rig import config
    from rig.runs import provenance
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    reg = CliRunner().invoke(main, ["register", "--json"])
    assert reg.exit_code == 0, reg.output
    reg_dir = json.loads([x for x in reg.stdout.splitlines() if x.startswith("{")][-1])["run_dir"]
    # a model of this rig's PSM1 (its provenance says so), parameters scaled by 1.1
    path = save_model(tmp_path / "model.json", standard=PSMDynamics().standard_params() * 1.1,
                      names=standard_parameter_names(), slope=400.0, gravity=np.array([0.0, 0.0, -9.81]),
                      provenance_info={"data_source": "test: nominal parameters scaled by 1.1",
                                       **provenance.live(config.load(), ["PSM1"], tmp_path)})
    res, data = _invoke(["--model", str(path), "--duration", "2", "--settle", "1.5", "--hold-after", "0.5"])
    assert res.exit_code == 0, res.output
    assert data["models"]["PSM1"]["file"] == str(path)
    assert data["models"]["PSM2"]["file"] is None  # the file is PSM1's: PSM2 keeps its own (nominal here)
    assert data["registration"] == f"registration {reg_dir}"
    assert data["max_error_during_motion"] < 0.25


def test_model_file_effects_are_fed_forward_and_the_rest_named(tmp_path):
    """A model file from `rig discrepancy` carries effects: the slaves' feedforward adds
    those it can (here a joint-3 spring and friction profile) and the result names the ones
    it cannot (a play). The simulated arms' plants are that model file too."""
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    effects = [{"name": "spring", "joint": 3, "params": {"k": 30.0, "q0": 0.08}},
               {"name": "position_friction", "joint": 3,
                "params": {"period": 0.03, "harmonics": 1, "a_sin": [0.3], "a_cos": [0.0]}},
               {"name": "backlash", "joint": 1, "params": {"width": 0.004, "motor_inertia": 0.03}}]
    path = save_model(tmp_path / "model.json", standard=PSMDynamics().standard_params(),
                      names=standard_parameter_names(), slope=400.0, gravity=np.array([0.0, 0.0, -9.81]),
                      extra={"effects": effects})
    toml = tmp_path / "rig.toml"
    toml.write_text('[arms.PSM1]\nplant_model = "model.json"\n[arms.PSM2]\nplant_model = "model.json"\n'
                    'base_xyz = [1.0728, 0.0, 0.0]\nbase_rpy = [0.0, 0.0, 3.141592653589793]\n')
    # the file was not measured on a rig: using it for this one's controllers is a choice
    res = CliRunner().invoke(main, ["--config", str(toml), "cooperative", "--model", str(path), "--duration", "2",
                                    "--settle", "1.5", "--hold-after", "0.5", "--json", "--force-model"])
    assert res.exit_code == 0, res.output
    data = json.loads([x for x in res.stdout.splitlines() if x.startswith("{")][-1])
    assert data["warnings"] == [f"--force-model: {path} used although it carries no provenance (written by an "
                                "older dvrk-rig or by hand)"]
    for arm in ("PSM1", "PSM2"):  # forced and naming no arm: every arm's
        assert data["models"][arm]["note"] == (f"{arm}: identified model {path} with its effects spring@3, "
                                               "position_friction@3, backlash@1")
    assert data["model_effects"]["fed_forward"] == ["spring@3", "position_friction@3"]
    assert [s["name"] for s in data["model_effects"]["not_fed_forward"]] == ["backlash"]
    assert data["max_error_during_motion"] < 0.25


def test_a_run_that_misses_its_tolerance_ends_failed_not_completed():
    """The motion runs to its end, but the tension strays beyond the tolerance it was
    given: status 'failed' with what was missed in result.json, the recording's stop
    record and the last stderr line, and exit code 4 (a safety abort is 3)."""
    from rig.runs.recording import read_recording
    from rig.commands.exit_codes import EXIT_MISSED

    res, data = _invoke(["--force", "5", "--duration", "1", "--settle", "1.5", "--hold-after", "0.2",
                         "--tolerance", "0.01"])
    assert res.exit_code == EXIT_MISSED, res.output
    assert data["status"] == "failed" and "above the tolerance 0.01 N" in data["error"]
    assert _run_dir_result(data)["status"] == "failed"
    rec = read_recording(os.path.join(data["run_dir"], "run.mcap"))
    assert rec.stop["status"] == "failed" and rec.stop["error"] == data["error"]
    last = [ln for ln in res.stderr.splitlines() if ln.strip()][-1]
    assert last.startswith("rig cooperative: failed: max |F - 5 N| while moving")


def test_a_tension_that_never_settles_is_missed():
    from procedures.cooperative_report import missed_bound

    params = {"tolerance": 0.5, "force": 5.0, "settle": 2.0, "duration": 5.0, "hold_after": 2.0}
    # the string that was never tensioned: max error 5.07 N, settling 9.00 s of 9.00 s
    assert "never settled" in missed_bound({"settling_time": 9.0, "max_error_during_motion": 5.073}, params)
    assert missed_bound({"settling_time": 1.1, "max_error_during_motion": 0.12}, params) is None
