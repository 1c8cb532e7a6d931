"""The lab's whole chain over the wire: `rig sim` in one process, every procedure in another.

rig sim's arms keep the dVRK's operating state (they start DISABLED, drop motion commands
until enabled and homed): each procedure enables and homes the arms it opens when it
connects, so the chain runs with state handling on throughout.

One `rig sim --sim-time` serves the module from a lab's rig.toml (ROS arms, the load cell
on a serial port that rig sim links to its pty, ROS mocap, rig sim's simulated operator,
`[ros] use_sim_time`: every procedure follows the world's clock in lockstep, so each
figure is the procedure's own, quiet or loaded, and asserted in every run), on a ROS
domain claimed for the module (tests/ros_domains.py); each test runs `rig <procedure>
--json` processes in the same folder, so a procedure finds the results of the ones it
needs in logs/, as in a lab. No test relies on another having run: what a procedure needs
(the load cell's calibration, the registration, the identified model, the friction ramp)
is a module fixture that runs its procedure the first time a test asks for it, so the
tests pass in any order, alone or in any subset. A test that kills rig sim leaves it dead;
the next test gets a fresh one on the same folder and domain (the logs stay). Durations
are short; the figures are checked against the simulated rig's truth (the nominal PSM
geometry and parameters, and the configured arm placement, which rig sim serves).
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig, completed  # noqa: E402
from tests.ros_domains import ros_environment  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]

#: the chain's identify options (short; its excitation design is cached by its inputs)
IDENTIFY = ("identify", "--arm", "PSM1", "--duration", "10", "--starts", "1", "--iterations", "5", "--no-plots")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The module's lab folder and its rig sim (a domain of its own, held to the end)."""
    with ServedRig(tmp_path_factory.mktemp("lab"), sim_time=True) as rig:
        yield rig


def _running(lab: ServedRig) -> ServedRig:
    """`lab` with its rig sim up and its arms out of FAULT: a fresh one on the same folder
    and domain if a test killed it, or a procedure that failed left an arm in FAULT (which,
    as on a dVRK, only a person clears: the next test would fail on it, not on its own)."""
    if not lab.running or lab.faulted:
        lab.restart()
    return lab


@pytest.fixture
def served(lab):
    return _running(lab)


# -- what procedures need, made once per module by the first test that asks ---------------
@pytest.fixture(scope="module")
def calibrated_cell(lab):
    """A completed `rig loadcell-calibrate` in the lab's logs (what `rig cooperative` opens the cell with)."""
    return completed(_running(lab).run("loadcell-calibrate", "--seconds", "0.5"), "loadcell-calibrate")


@pytest.fixture(scope="module")
def registered(lab):
    """A completed `rig register` (by touch) in the lab's logs."""
    return completed(_running(lab).run("register", "--points", "6"), "register")


@pytest.fixture(scope="module")
def identified(lab):
    """A completed `rig identify` of PSM1 in the lab's logs (the model)."""
    return completed(_running(lab).run(*IDENTIFY), "identify")


@pytest.fixture(scope="module")
def ramped(lab, identified):
    """A completed `rig friction-ramp` on the identified model (its stick-slip terms join the model)."""
    return completed(_running(lab).run("friction-ramp", "--ramp-time", "1.5", "--speeds", "0.01,0.02,0.04",
                                       "--no-plots"), "friction-ramp")


@pytest.fixture(scope="module")
def identified_psm2(lab):
    """A completed `rig identify` of PSM2: each arm runs on its own model, never another's,
    and an arm of a served (real) rig without one is refused (the guide identifies both)."""
    return completed(_running(lab).run(*IDENTIFY[:2], "PSM2", *IDENTIFY[3:]), "identify PSM2")


@pytest.fixture
def cooperative_ready(lab, calibrated_cell, registered, identified, identified_psm2, ramped):
    """The lab with everything `rig cooperative` uses: the cell's calibration, the
    registration and each arm's identified model (PSM1's with its friction ramp); rig sim running."""
    return _running(lab)


def _cfg(served):
    from rig import config

    return config.load(served.folder / "rig.toml")


def test_loadcell_calibrate_hangs_masses_through_the_operator(lab, calibrated_cell):
    doc = calibrated_cell
    assert doc["device"]["port"] == str(lab.folder / "loadcell")
    # the simulated operator hung 0.5 kg: the check reads its weight back (noise 20 mN rms)
    assert abs(doc["check"]["error_n"]) < 0.02


def test_link_lengths(served):
    from procedures.link_lengths import nominal_lengths

    if served.runs_since_start:  # a fresh rig sim: its arms DISABLED, as a console's at power-up
        served.restart()
    out = served.run("link-lengths", "--q1-range", "0.5", "--q2-range", "0.4", "--passes", "1", "--q3-stroke", "0.05")
    doc = completed(out, "link-lengths")
    # rig sim's arms start DISABLED, as a dVRK's: the first procedure to move PSM1 enabled
    # and homed it through its operating state when connecting
    assert "enabling and homing PSM1 (PSM1 DISABLED, not homed;" in out.stderr, out.stderr[-3000:]
    assert "PSM1: ENABLED and homed in" in out.stderr
    true = nominal_lengths()  # the geometry rig sim's arms have
    for key in ("l1", "l2", "l3", "l4"):
        assert abs(doc["lengths"][key]["value"] - true[key]) < 0.003, (key, doc["lengths"][key], true[key])


def test_calibrate_rcm(served):
    from rig.model import psm_kinematics as K

    doc = completed(served.run("calibrate-rcm", "--arm", "all", "--duration", "6", "--q1-range", "0.5",
                         "--q2-range", "0.4"), "calibrate-rcm")
    cfg = _cfg(served)
    for arm in ("PSM1", "PSM2"):
        true = (cfg.base_matrix(arm) @ K.RCM_FRAME)[:3, 3]
        assert np.linalg.norm(np.array(doc["arms"][arm]["rcm"]) - true) < 0.002, arm
    # rig sim occludes nothing: the frames came whole, however late the process took them
    # (assembled by stamp, a body still sending waited for; 70-90 % were split under two
    # CPU burners when frames left by the distance of their stamps)
    tracker = doc["tracker"]
    assert tracker["frames"] > 0 and tracker["incomplete"] <= 0.05 * tracker["frames"], tracker


def test_register_by_touch(lab, registered):
    from procedures.register import truth_errors

    doc = registered
    T = np.array(doc["transforms"]["PSM2"]["T_ref_rcm_arm_rcm"])
    err = truth_errors(_cfg(lab), ["PSM1", "PSM2"], {"PSM1": np.eye(4), "PSM2": T})["PSM2"]
    assert err["rcm_translation_error"] < 0.002 and err["rcm_rotation_error_deg"] < 0.5, err


def test_identify(identified):
    doc = identified
    assert doc["checks"]["sdp"] is True
    # a sanity bound: the accuracy over the wire (0.02-0.18 on joint 1, by the machine's
    # load) is bench_hil's figure against its 0.1 target
    assert np.all(np.array(doc["validation_moving"]["sdp"]) < 0.25), doc["validation_moving"]


def test_friction_ramp(ramped):
    from rig.model.psm_dynamics import PSMParameters

    doc = ramped
    fc_true = PSMParameters().drive.Fc[2]
    fc = doc["fits"]["viscous_coulomb"]["Fc"]
    assert abs(fc - fc_true) < 0.25 * fc_true, (fc, fc_true)


#: the targets of the loop over the wire on simulated time (issue 44): the same figures as
#: in one process, quiet or loaded, since the world waits for the loop
MAX_ERROR_WHILE_MOVING = 0.25  # N
MAX_OVERSHOOT = 0.5  # N


@pytest.mark.parametrize("kind", ["spring", pytest.param("string", marks=pytest.mark.slow)])
def test_cooperative_holds_5_newtons(cooperative_ready, kind):
    """Over the wire the loop holds the object: the slaves' impedance in the arm (servo_ci),
    the loop at the rate the arms publish up to ARM_LOOP_MAX_RATE, on the world's clock in
    lockstep: completed, within 0.25 N of 5 N while moving and 0.5 N of overshoot, in
    every run. bench/bench_cooperative_wire.py gives the figures quiet and loaded."""
    from procedures.cooperative import ARM_LOOP_MAX_RATE

    served = cooperative_ready
    doc = completed(served.run("cooperative", "--force", "5", "--object", kind, "--move", "0.03,0,0",
                               "--duration", "2", "--settle", "1.5", "--hold-after", "0.5"), f"cooperative {kind}")
    timing = doc["loop_timing"]
    assert timing["rate_hz"] == ARM_LOOP_MAX_RATE, doc
    assert doc["max_error_during_motion"] <= MAX_ERROR_WHILE_MOVING, (doc["summary"], timing)
    assert doc["overshoot"] <= MAX_OVERSHOOT, doc["summary"]
    # the world waited for every tick: no sample late, no force loop held for an old tension
    assert timing["arm_clock_jumps"] == 0 and timing["force_hold_per_10k"] == 0, timing
    assert doc["slave_control"].startswith("arm impedance (servo_ci"), doc["slave_control"]
    assert doc["registration"].startswith("registration "), doc["registration"]
    # each arm on its own identified model, named by file
    files = {arm: m["file"] for arm, m in doc["models"].items()}
    assert set(files) == {"PSM1", "PSM2"} and all(files.values()) and files["PSM1"] != files["PSM2"], files


#: the loop closed on the model's estimate, judged on the cell (issue 47's target: the
#: thesis' hardware figure with its load cell)
MAX_ERROR_ON_THE_ESTIMATE = 0.5  # N


@pytest.mark.parametrize("kind", ["spring", pytest.param("string", marks=pytest.mark.slow)])
def test_cooperative_on_the_models_estimate(cooperative_ready, kind):
    """Over the wire the loop closes on the tension the arms' joints and efforts say
    (--tension-source model): the cell only records and judges. Completed, within 0.5 N
    of 5 N while moving, and the estimate within 0.3 N RMS of the cell."""
    doc = completed(cooperative_ready.run("cooperative", "--force", "5", "--object", kind, "--move", "0.03,0,0",
                                          "--duration", "2", "--settle", "1.5", "--hold-after", "0.5",
                                          "--tension-source", "model"), f"cooperative {kind} on the estimate")
    est = doc["tension_estimate"]
    assert est["loop_closed_on"] == "model estimate", est
    assert doc["max_error_during_motion"] <= MAX_ERROR_ON_THE_ESTIMATE, (doc["summary"], est)
    assert doc["overshoot"] <= MAX_OVERSHOOT, doc["summary"]
    assert est["rms_difference"] <= 0.3 and est["max_difference"] <= 0.6, est


def test_discrepancy_on_the_identify_run(served, identified):
    doc = completed(served.run("discrepancy", identified["run_dir"]), "discrepancy")
    assert all(math.isfinite(v) for v in doc["baseline"]["heldout_rms"])


# ------------------------------------------------------------------------------ faults
# Each fault ends the procedure with one line on stderr naming the device and what to check,
# a non-zero exit, no traceback, the arms it moved held and the recording closed with the
# reason. The results of the chain (model, registration, calibration) are used: the
# cooperative_ready fixture makes them when they are not there yet.

def _one_clear_line(out, *words: str) -> None:
    assert out.code != 0
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    for w in words:
        assert w in out.last_line, out.last_line


def _stopped_recording(out, reason_words: tuple[str, ...]) -> dict:
    from rig.runs.recording import read_recording

    assert out.doc is not None and out.doc["status"] == "aborted", out.stderr[-2000:]
    for w in reason_words:
        assert w in out.doc["error"], out.doc["error"]
    rec = read_recording(os.path.join(out.doc["run_dir"], "run.mcap"))
    assert rec.finalised and rec.stop["status"] == "aborted" and rec.stop["error"] == out.doc["error"]
    return rec.stop


def _cooperative_args(duration: float = 6.0) -> list[str]:
    return ["cooperative", "--force", "5", "--object", "spring", "--move", "0.02,0,0", "--duration", str(duration),
            "--settle", "1", "--hold-after", "0"]


@pytest.mark.parametrize("args", [
    ["link-lengths", "--passes", "1"],
    ["calibrate-rcm", "--arm", "PSM1", "--duration", "6", "--q1-range", "0.5", "--q2-range", "0.4"],
    ["register", "--points", "6"],
    ["identify", "--arm", "PSM1", "--duration", "10", "--starts", "1", "--iterations", "5", "--no-plots"],
    ["friction-ramp", "--no-plots"],
    ["cooperative", "--force", "5", "--object", "spring", "--duration", "1"],
], ids=lambda a: a[0])
def test_wrong_domain_is_one_line_naming_the_topic_and_domain(served, args, ros_domain, request):
    # every procedure that drives the arms; a short connect timeout keeps the wait brief.
    # The wrong domain is one claimed for the test: nobody's nodes are on it.
    if args[0] == "cooperative":  # it finds its calibration, registration and model before connecting
        request.getfixturevalue("cooperative_ready")
    short = served.folder / "short-connect.toml"
    text = (served.folder / "rig.toml").read_text()
    short.write_text(text.replace("[ros]\n", "[ros]\nconnect_timeout = 2.0\n") if "[ros]\n" in text
                     else text + "\n[ros]\nconnect_timeout = 2.0\n")
    out = served.run("--config", str(short), *args, env=served.env(ROS_DOMAIN_ID=str(ros_domain)))
    # on simulated time the first thing a procedure waits for is the simulator's clock
    _one_clear_line(out, "/clock", f"ROS_DOMAIN_ID={ros_domain}", "no simulated time within 2 s",
                    "rig sim --sim-time")


def test_a_pty_that_is_not_a_load_cell(cooperative_ready):
    served = cooperative_ready
    master, slave = os.openpty()  # nobody answers on it
    try:
        other = served.folder / "silent.toml"
        other.write_text((served.folder / "rig.toml").read_text().replace(
            f'port = "{served.folder / "loadcell"}"', f'port = "{os.ttyname(slave)}"'))
        out = served.run("--config", str(other), *_cooperative_args(1.0))
        _one_clear_line(out, "load cell", os.ttyname(slave))
    finally:
        os.close(master)
        os.close(slave)


def test_a_missing_calibration(cooperative_ready, tmp_path):
    import shutil

    served = cooperative_ready
    logs = tmp_path / "logs"
    for run in (served.folder / "logs").iterdir():  # everything but the load-cell calibration
        if run.is_dir() and not run.name.endswith("loadcell-calibrate"):
            shutil.copytree(run, logs / run.name)
    out = served.run(*_cooperative_args(1.0), env=served.env(RIG_LOGS=str(logs)))
    _one_clear_line(out, "loadcell-calibrate")


#: the first progress bar of the cooperative procedure's hold loop: connected, the object
#: attached and holding (a fixed delay would depend on how long connecting took)
HOLDING = "hold the tension while moving ["


def test_load_cell_unplugged_mid_run(cooperative_ready):
    from drivers.common.ros_session import RosSession
    from drivers.operator.driver import RosOperator

    served = cooperative_ready

    def pull_the_cable():
        with ros_environment(served.domain):
            session = RosSession("test_person")
            session.start()
            RosOperator(session.control, timeout=10.0).unplug("loadcell")
            session.close()

    try:
        out = served.run(*_cooperative_args(10.0), when=(HOLDING, pull_the_cable))
    finally:
        served.stop(keep_domain=True)  # its cell stays unplugged: the next test gets a fresh rig sim
    _one_clear_line(out, "load cell", "aborted")
    stop = _stopped_recording(out, ("load cell",))
    assert sorted(stop["held"]) == ["PSM1", "PSM2"]


def test_rig_sim_killed_mid_run_is_seen_by_its_clock(served):
    """It kills the module's rig sim (the next test gets a fresh one). On simulated time a
    dead simulator stops the clock every age is counted on: the procedure sees the clock
    stand still while it waits for it (drivers.common.time_base.STALL s of wall time), in one line
    naming /clock. The wall clock's watchdog is the fault matrix's (tests/hil/fault_matrix.py)."""
    import re

    from drivers.common.time_base import STALL

    # the chain's identify options: killed once the excitation streams
    out = served.run(*IDENTIFY, when=("run the excitation trajectory [", served.kill))
    _one_clear_line(out, "aborted", "/clock", "stood still", "rig sim --sim-time")
    stop = _stopped_recording(out, ("/clock",))
    assert stop["held"] == ["PSM1"]
    age = float(re.search(r"stood still for ([0-9.]+) s", out.doc["error"]).group(1))
    assert age >= STALL, out.doc["error"]


def test_rig_sim_killed_mid_cooperative_holds_both_arms(cooperative_ready):
    """The module's rig sim, killed while the cooperative procedure holds the object (the
    next test gets a fresh one). Its load cell's pty closes with it and the arms' streams
    stop: whichever the run sees first ends it, in one line."""
    served = cooperative_ready
    out = served.run(*_cooperative_args(10.0), when=(HOLDING, served.kill))
    assert out.code == 3 and "Traceback" not in out.stderr, out.stderr[-3000:]
    assert "aborted" in out.last_line
    assert any(w in out.last_line for w in ("/clock", "stale stream", "load cell")), out.last_line
    stop = _stopped_recording(out, ())
    assert sorted(stop["held"]) == ["PSM1", "PSM2"]
