"""The dVRK's own Python client, call by call, against a running dVRK (here: `rig sim`).

Run in a process whose environment imports the unmodified client (tests/hil/dvrk_client.py
makes it): `python dvrk_client_calls.py PSM1 [--system system|console]`. It drives the
arm through every CRTK family of `dvrk.psm` (and `dvrk.system` or the 2.3 `dvrk.console`)
and prints one JSON document on stdout: for each call, what it returned (numbers as
lists), whether it raised, and how long it took. The test (test_dvrk_client.py) checks
the numbers against the project's own kinematics; this program only records.

Nothing here is of the client's code: it is a user of it, as a lab's script is.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback

import numpy


def frame(f) -> list:
    """A PyKDL.Frame as a 4x4 list."""
    return [[f.M[i, 0], f.M[i, 1], f.M[i, 2], f.p[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def plain(value):
    import PyKDL

    if isinstance(value, PyKDL.Frame):
        return frame(value)
    if isinstance(value, numpy.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [plain(v) for v in value]
    if isinstance(value, (numpy.floating, numpy.integer)):
        return value.item()
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    return repr(value)


class Recorder:
    def __init__(self):
        self.calls: dict[str, dict] = {}

    def __call__(self, name: str, fn, *args, **kwargs):
        t0 = time.monotonic()
        try:
            value = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - recorded, the next call goes on
            self.calls[name] = {"ok": False, "error": f"{type(exc).__name__}: {exc}",
                                "trace": traceback.format_exc()[-1500:], "s": time.monotonic() - t0}
            return None
        self.calls[name] = {"ok": True, "value": plain(value), "s": time.monotonic() - t0}
        return value


#: s of wall time the client's own waits are given (enable, home, a move's wait): caps, so
#: that a loaded machine's slowness is waited out; a command that never completes still fails
CAP = 60.0


def until(read, done, limit: float = CAP):
    """What `read()` returns once `done(value)` holds, or after `limit` s (the caller's
    assertion then fails on it). This rig sim runs on the wall clock, as against a real
    console: on a loaded machine a fixed sleep measures the machine; a wait for what the
    command does measures the command."""
    t0 = time.monotonic()
    while True:
        value = read()
        if done(value) or time.monotonic() - t0 > limit:
            return value
        time.sleep(0.01)


def at_rest(psm, goal=None, tolerance: float = 3e-3, speed: float = 2e-3):
    """Wait (until) for the arm at rest, at `goal` (joints, within `tolerance`) if given:
    joints 1-3 slower than `speed` (rad/s, m/s). What a read "at rest" needs, however long
    the machine takes to get the arm there."""
    def still(v):
        return bool(numpy.all(numpy.abs(numpy.asarray(v[0])[:3]) < speed))

    if goal is not None:
        until(psm.measured_jp, lambda v: numpy.allclose(v[0], goal, atol=tolerance))
    until(psm.measured_jv, still)


def run(ral, arm_name: str, system_name: str) -> dict:
    import crtk
    import dvrk
    import PyKDL

    rec = Recorder()
    psm = dvrk.psm(ral=ral, arm_name=arm_name)
    if system_name == "console":
        console = dvrk.console(ral=ral)
        system = None
    else:
        system = dvrk.system(ral=ral)
        console = dvrk.console(ral=ral)
    ral.spin()
    rec("check_connections", ral.check_connections, CAP)
    rec("enable", psm.enable, CAP)
    rec("home", psm.home, CAP)
    rec("operating_state", psm.operating_state)
    rec("is_homed", psm.is_homed)
    rec("is_enabled", psm.is_enabled)
    # joint space: a move to where the tool is past the cannula, straight
    goal = numpy.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    h = rec("move_jp", psm.move_jp, goal)
    rec("move_jp.wait", h.wait, False, CAP) if h else None
    time.sleep(0.5)
    at_rest(psm, goal)  # the readings below are compared "at rest", a few ms apart
    rec("measured_js", psm.measured_js)
    rec("measured_jp", psm.measured_jp)
    rec("measured_jv", psm.measured_jv)
    rec("measured_jf", psm.measured_jf)
    rec("setpoint_js", psm.setpoint_js)
    rec("setpoint_jp", psm.setpoint_jp)
    rec("measured_cp", psm.measured_cp)
    rec("setpoint_cp", psm.setpoint_cp)
    rec("measured_cv", psm.measured_cv)
    rec("local.measured_cp", psm.local.measured_cp)
    rec("local.setpoint_cp", psm.local.setpoint_cp)
    rec("body.measured_cf", psm.body.measured_cf)
    rec("spatial.measured_cf", psm.spatial.measured_cf)
    rec("body.jacobian", psm.body.jacobian)
    rec("spatial.jacobian", psm.spatial.jacobian)
    jp, _ = psm.measured_jp()
    rec("forward_kinematics", psm.forward_kinematics, jp)
    rec("forward_kinematics.3", psm.forward_kinematics, jp[:3])
    rec("local.forward_kinematics", psm.local.forward_kinematics, jp)
    cp, _ = psm.local.measured_cp()
    rec("inverse_kinematics.cp", lambda: cp)
    rec("inverse_kinematics.jp", lambda: jp)
    rec("inverse_kinematics", psm.inverse_kinematics, jp, cp)
    # a move to where the arm is: busy rises and falls, the wait returns at once
    h = rec("move_jp.same", psm.move_jp, jp)
    rec("move_jp.same.wait", h.wait, False, CAP) if h else None
    # a move with a busy loop, as dvrk_move_wait_test.py
    goal = numpy.copy(jp)
    goal[0] += 0.1
    h = psm.move_jp(goal)
    loops = 0
    t0 = time.monotonic()
    while h.is_busy() and time.monotonic() - t0 < CAP:  # a hang guard, not a speed bound
        loops += 1
        time.sleep(0.001)
    rec.calls["move_jp.busy_loop"] = {"ok": True, "value": loops, "s": time.monotonic() - t0}
    time.sleep(0.5)
    at_rest(psm, goal)
    rec("after_busy_loop.measured_jp", psm.measured_jp)
    # relative moves
    before_jr, _ = psm.measured_jp()
    h = rec("move_jr", psm.move_jr, numpy.array([-0.1, 0.05, 0.0, 0.2, 0.0, 0.0]))
    rec("move_jr.wait", h.wait, False, CAP) if h else None
    time.sleep(0.5)
    at_rest(psm, before_jr + numpy.array([-0.1, 0.05, 0.0, 0.2, 0.0, 0.0]), tolerance=5e-3)
    rec("after_move_jr.measured_jp", psm.measured_jp)
    rec("after_move_jr.setpoint_jp", psm.setpoint_jp)
    # servo_jp: a 2 s sine on joint 1 at 100 Hz, then servo_jr
    start, _ = psm.setpoint_jp()
    rate = ral.create_rate(100)
    for i in range(201):
        g = numpy.copy(start)
        g[0] = start[0] + 0.05 * math.sin(2 * math.pi * i / 200)
        psm.servo_jp(g)
        rate.sleep()
    time.sleep(1.0)
    until(psm.measured_jp, lambda v: numpy.allclose(v[0], start, atol=2e-3))  # the sine's end reached
    rec("after_servo_jp.measured_jp", psm.measured_jp)
    before, _ = psm.setpoint_jp()
    rec("servo_jr", psm.servo_jr, numpy.array([0.0, 0.0, 0.01, 0.0, 0.0, 0.0]))
    time.sleep(0.5)
    until(psm.setpoint_jp, lambda v: abs(v[0][2] - before[2]) > 0.005)  # the console has taken it
    rec("after_servo_jr.setpoint_jp", psm.setpoint_jp)
    rec("after_servo_jr.measured_jp", psm.measured_jp)
    # cartesian: move_cp 2 cm in x, then servo_cp back in 1 s
    cp0, _ = psm.setpoint_cp()
    rec("move_cp.start", lambda: cp0)
    g = PyKDL.Frame(cp0.M, cp0.p + PyKDL.Vector(0.02, 0.0, 0.0))
    h = rec("move_cp", psm.move_cp, g)
    rec("move_cp.wait", h.wait, False, CAP) if h else None
    time.sleep(0.5)
    until(psm.measured_cp, lambda v: (v[0].p - g.p).Norm() < 1e-3)
    rec("after_move_cp.measured_cp", psm.measured_cp)
    rec("after_move_cp.setpoint_cp", psm.setpoint_cp)
    for i in range(1, 101):
        s = i / 100.0
        psm.servo_cp(PyKDL.Frame(cp0.M, cp0.p + PyKDL.Vector(0.02 * (1.0 - s), 0.01 * s, 0.0)))
        rate.sleep()
    time.sleep(0.5)
    until(psm.measured_cp, lambda v: (v[0].p - (cp0.p + PyKDL.Vector(0.0, 0.01, 0.0))).Norm() < 1e-3)
    rec("after_servo_cp.measured_cp", psm.measured_cp)
    rec("after_servo_cp.goal", lambda: PyKDL.Frame(cp0.M, cp0.p + PyKDL.Vector(0.0, 0.01, 0.0)))
    # trajectory ratio
    rec("trajectory_j_set_ratio", psm.trajectory_j_set_ratio, 0.5)
    time.sleep(0.5)
    until(psm.trajectory_j_get_ratio, lambda v: abs(v - 0.5) < 1e-6)
    rec("trajectory_j_get_ratio", psm.trajectory_j_get_ratio)
    psm.trajectory_j_set_ratio(1.0)
    # jaw
    h = rec("jaw.open", psm.jaw.open, math.radians(60.0))
    rec("jaw.open.wait", h.wait, False, CAP) if h else None
    time.sleep(0.5)
    until(psm.jaw.measured_jp, lambda v: abs(v[0][0] - math.radians(60.0)) < 0.01)
    rec("jaw.after_open.measured_jp", psm.jaw.measured_jp)
    rec("jaw.setpoint_js", psm.jaw.setpoint_js)
    rec("jaw.measured_js", psm.jaw.measured_js)
    h = rec("jaw.close", psm.jaw.close)
    rec("jaw.close.wait", h.wait, False, CAP) if h else None
    time.sleep(0.5)
    until(psm.jaw.measured_jp, lambda v: v[0][0] < 0.01)
    rec("jaw.after_close.measured_jp", psm.jaw.measured_jp)
    for i in range(100):
        psm.jaw.servo_jp(numpy.array([math.radians(30.0) * i / 99.0]))
        rate.sleep()
    time.sleep(0.5)
    until(psm.jaw.measured_jp, lambda v: abs(v[0][0] - math.radians(30.0)) < 0.02)
    rec("jaw.after_servo_jp.measured_jp", psm.jaw.measured_jp)
    # efforts. A wrench and the joint state of the same period (the same stamp) first: the
    # wrench is what the efforts make through the Jacobians. Then each effort command, for a
    # tenth of a second from a held arm and back to hold: the effort that holds the arm, the
    # same as a spatial and as a body wrench (through the Jacobians the arm publishes), zero
    # with gravity compensation, free; the set-point's effort (what the arm applies, with
    # the joints of the same period) is recorded against the command.
    rec("body_set_cf_orientation_absolute", psm.body_set_cf_orientation_absolute, False)
    time.sleep(0.5)
    for kind, cf in (("spatial", psm.spatial.measured_cf), ("body", psm.body.measured_cf)):
        t_end = time.monotonic() + CAP
        while time.monotonic() < t_end:
            w, t_w = cf()
            js = psm.measured_js()
            if abs(js[3] - t_w) < 1e-6:
                rec(f"effort.{kind}_wrench", lambda w=w: w)
                rec(f"effort.{kind}_wrench_js", lambda js=js: js)
                break
            time.sleep(0.001)
    rest = rec("effort.rest_js", psm.measured_js)
    tau = numpy.array(rest[2])
    # each wrench through the Jacobian the arm publishes just before it is sent (held still)
    def wrench(kind: str):
        J = (psm.spatial if kind == "spatial" else psm.body).jacobian()[0]
        w = numpy.linalg.solve(J.T, tau)
        rec(f"{kind}_cf.wrench", lambda: w)
        (psm.spatial if kind == "spatial" else psm.body).servo_cf(w)

    commands = {"servo_jf": lambda: psm.servo_jf(tau), "spatial_cf": lambda: wrench("spatial"),
                "body_cf": lambda: wrench("body")}
    def setpoint_after(sent: float, also=lambda sp: True):
        """The first setpoint_js stamped 20 ms or more after `sent` (the arm's own clock)
        of a period in which the arm runs on efforts: its position set-point is the
        measured position of the same period (rig sim's effort mode; in position mode it
        is the goal the PID holds), and `also(setpoint_js)`. So the command has reached the
        arm, however late a loaded machine delivered it; after CAP s, the newest setpoint_js."""
        t_end = time.monotonic() + CAP
        while True:
            sp = psm.setpoint_js()
            js = psm.measured_js()
            on_efforts = sp[3] == js[3] and numpy.array_equal(numpy.asarray(sp[0])[:3], numpy.asarray(js[0])[:3])
            if (sp[3] >= sent + 0.02 and on_efforts and also(sp)) or time.monotonic() > t_end:
                return sp
            time.sleep(0.002)

    for name, command in commands.items():
        sent = ral.to_sec(ral.now())
        rec(name, command)
        rec(f"after_{name}.setpoint_js", setpoint_after, sent)
        psm.hold()
        time.sleep(0.3)
    rec("after_efforts.measured_jp", psm.measured_jp)
    rec("jaw.servo_jf", psm.jaw.servo_jf, numpy.array([0.0]))
    psm.hold()
    # gravity compensation: the arm adds its model's gravity torque to the command
    rec("use_gravity_compensation", psm.use_gravity_compensation, True)
    time.sleep(0.2)
    sent = ral.to_sec(ral.now())
    rec("servo_jf.gc", psm.servo_jf, numpy.zeros(6))
    # with the compensation on, the arm applies more than the zero command (use_gravity_compensation
    # and servo_jf travel on two topics: a loaded machine may deliver the second first)
    compensated = lambda sp: bool(numpy.any(numpy.asarray(sp[2])[:3] != 0.0))  # noqa: E731
    rec("after_servo_jf_gc.setpoint_js", setpoint_after, sent, compensated)
    psm.hold()
    time.sleep(0.3)
    sent = ral.to_sec(ral.now())
    rec("free", psm.free)
    rec("after_free.setpoint_js", setpoint_after, sent, compensated)
    rec("hold", psm.hold)
    time.sleep(1.0)
    at_rest(psm)  # held: the arm comes to rest where it was
    rec("after_hold.measured_js", psm.measured_js)
    time.sleep(0.3)
    rec("after_hold.later_jp", psm.measured_jp)
    rec("use_gravity_compensation.off", psm.use_gravity_compensation, False)
    rec("set_tool_present", psm.set_tool_present, True)
    rec("insert_jp", lambda: psm.insert_jp(0.1).wait(False, CAP))
    time.sleep(0.3)
    until(psm.measured_jp, lambda v: abs(v[0][2] - 0.1) < 1e-3)
    rec("after_insert.measured_jp", psm.measured_jp)
    # the console: what a lab's scripts publish there
    if system is not None:
        rec("system.beep", system.beep, 0.1, 440.0)
        rec("system.set_volume", system.set_volume, 0.5)
        rec("system.string_to_speech", system.string_to_speech, "rig sim")
    rec("console.teleop_set_scale", console.teleop_set_scale, 0.3)
    time.sleep(0.5)
    until(console.teleop_get_scale, lambda v: abs(v - 0.3) < 1e-9)
    rec("console.teleop_get_scale", console.teleop_get_scale)
    rec("console.teleop_select", console.teleop_select, "MTMR_PSM1")
    time.sleep(0.5)
    until(lambda: console.teleop_is_selected("MTMR_PSM1"), bool)
    rec("console.teleop_is_selected", console.teleop_is_selected, "MTMR_PSM1")
    # state: disable and enable again (the arm keeps is_homed, as the dVRK)
    rec("disable", psm.disable, CAP)
    rec("after_disable.operating_state", psm.operating_state)
    rec("enable.again", psm.enable, CAP)
    rec("home.again", psm.home, CAP)
    return rec.calls


def main() -> int:
    import crtk

    argv = crtk.ral.parse_argv(sys.argv[1:])
    parser = argparse.ArgumentParser()
    parser.add_argument("arm")
    parser.add_argument("--system", choices=["system", "console"], default="system")
    args = parser.parse_args(argv)
    ral = crtk.ral("dvrk_client_calls")
    calls = {}
    try:
        calls = run(ral, args.arm, args.system)
    finally:
        print(json.dumps(calls), flush=True)
        ral.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
