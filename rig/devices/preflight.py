"""The lab's preflight of its devices (`rig doctor`): each device of rig.toml asked, briefly,
whether it answers as the procedures need, one `Check` per line.

Nothing is moved, enabled or commanded: the arms' consoles are only listened to (their
measured_js and its rate from the stamps, their operating state, the ROS graph's
subscriptions to servo_ci), the load cell is identified and streams for half a second, the
mocap bodies are listened to, `rig sim`'s operator is looked for. Every wait is bounded
(`timeout` s of wall time per device at most; the devices on ROS share one wait).

A check is "ok", "todo" (a result not made yet: the line names the command that makes it;
not a failure) or "fail" with the exit code of its kind (rig.commands.exit_codes): a
device that does not answer as the procedures need is EXIT_ABORTED's kind (a device
fault), this machine's or rig.toml's set-up EXIT_INPUT's.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass

from rig.commands.exit_codes import EXIT_ABORTED, EXIT_INPUT

#: the procedures whose loops run at [rig] rate and refuse an arm's stream slower than
#: rig.devices.factory.RATE_MARGIN of it
RIG_RATE_PROCEDURES = ("link-lengths", "calibrate-rcm", "register", "identify", "friction-ramp")


@dataclass
class Check:
    """One line of the preflight: `what` is checked, `status` ok / todo / fail, `text`
    what was found and, unless ok, what to do; `code` the exit status a failure asks for."""

    what: str
    status: str
    text: str
    code: int = 0

    def line(self) -> str:
        return f"{self.status:<5} {self.what}: {self.text}"


def ok(what: str, text: str) -> Check:
    return Check(what, "ok", text)


def fail(what: str, text: str, code: int = EXIT_ABORTED) -> Check:
    return Check(what, "fail", text, code)


def todo(what: str, text: str) -> Check:
    return Check(what, "todo", text)


# ------------------------------------------------------------------ this machine
def environment(cfg) -> list[Check]:
    """Python, the ROS 2 packages, crtk_msgs, the domain and discovery range."""
    import importlib.metadata

    from drivers.common import crtk_messages

    out = [ok("python", f"{sys.version.split()[0]} ({sys.executable})")]
    ros_arms = [n for n, a in cfg.arms.items() if a["driver"] == "ros"]
    uses_ros = bool(ros_arms) or cfg.mocap["driver"] == "ros" or cfg.operator["driver"] == "ros"
    try:
        import rclpy  # noqa: F401

        version = importlib.metadata.version("ros-jazzy-rclpy")
        out.append(ok("ROS 2", f"rclpy {version} (ROS 2 Jazzy from PyPI)"))
    except Exception as exc:  # noqa: BLE001 - any failure to import is this line
        out.append(fail("ROS 2", f"rclpy does not import ({str(exc).splitlines()[0] if str(exc) else exc!r}); "
                        "reinstall: `.venv/bin/pip install -e .` (do not source a system ROS setup)", EXIT_INPUT))
        return out
    why = crtk_messages.problem()
    if why is None:
        out.append(ok("crtk_msgs", "the dVRK's CRTK messages load"))
    elif ros_arms:
        out.append(fail("crtk_msgs", why, EXIT_INPUT))
    else:
        out.append(ok("crtk_msgs", f"not needed by this rig's simulated arms ({why})"))
    if not uses_ros:
        return out
    raw = os.environ.get("ROS_DOMAIN_ID", "")
    scope = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") or "SUBNET (the default)"
    try:
        domain = int(raw) if raw else 0
    except ValueError:
        domain = -1
    if not 0 <= domain <= 232:
        out.append(fail("ROS domain", f"ROS_DOMAIN_ID={raw!r} is not a domain (0-232): `export ROS_DOMAIN_ID=<the "
                        "console's>` in every terminal", EXIT_INPUT))
    else:
        note = "" if raw else " (unset: the console must be on 0 too)"
        if domain > 101:
            note += "; ROS 2 on Linux recommends 0-101 (102-232 may meet the ephemeral ports)"
        out.append(ok("ROS domain", f"ROS_DOMAIN_ID={domain}{note}; discovery {scope}"
                      + (" (the console must run on this PC)" if scope == "LOCALHOST" else "")))
    return out


# ------------------------------------------------------------------ the arms' consoles
def _rate_text(heard: float) -> str:
    return f"{heard:.0f} Hz published (console -p {1.0 / heard:.3g} s)" if heard > 0 else "no rate heard"


def arm_checks(cfg, arm, name: str) -> list[Check]:
    """One arm's console, once its messages came: the rate against what each procedure
    needs, the clock, the operating state, servo_ci subscribed."""
    from rig.control.arm_loop_rates import ARM_LOOP_MIN_RATE, arm_loop_min_rate
    from rig.devices.factory import RATE_MARGIN

    out = []
    heard = arm.published_rate()
    need = float(cfg.rig["rate"])
    kind, held_by = cfg.object["kind"], len(cfg.object["arms"] or list(cfg.arms)[:2])
    coop = arm_loop_min_rate(kind, held_by)
    coop_what = f"cooperative ({kind}{', three arms' if held_by > 2 else ''}) needs {coop:g} Hz"
    topic = arm.topic["measured_js"]
    if heard < RATE_MARGIN * need:
        served = (f" (cooperative's {coop:g} Hz is met)" if heard >= RATE_MARGIN * coop else f"; {coop_what}")
        out.append(fail(f"{name} console", f"{topic} {_rate_text(heard)}; {', '.join(RIG_RATE_PROCEDURES)} need "
                        f"{need:g} Hz ([rig] rate){served}: start the console with `dvrk_system -p {1.0 / need:g}` "
                        f"(or `rig sim --ros-period {1.0 / need:g}`), or set [rig] rate = {max(1, int(round(heard)))} in "
                        f"{cfg.source}"))
    elif heard < RATE_MARGIN * coop:
        out.append(fail(f"{name} console", f"{topic} {_rate_text(heard)}; {coop_what}: start the console with "
                        f"`dvrk_system -p {1.0 / coop:g}`"))
    else:
        string = ARM_LOOP_MIN_RATE["string"]
        note = "" if heard >= RATE_MARGIN * string else f" (not `cooperative --object string`: {string:g} Hz)"
        out.append(ok(f"{name} console", f"{topic} {_rate_text(heard)}: every procedure's loop served ([rig] rate "
                      f"{need:g} Hz, {coop_what}){note}"))
    period = cfg.ros["period"]
    if heard > 0 and abs(period * heard - 1.0) > 0.25:
        # it only sets the stale limits, floored at 2 s for ROS streams: a note, not a fault
        out[-1].text += (f"; [ros] period says {period:g} s: set it to {1.0 / heard:.3g} (only the stale limits "
                         f"follow it, {cfg.arms[name]['watchdog']:g} s here)")
    stamp = arm.last_stamp()
    simulated = 0.0 <= stamp < 1e9
    if simulated and not cfg.ros["use_sim_time"]:
        out.append(fail(f"{name} clock", f"stamped {stamp:.3f} s, a simulator's clock (`rig sim --sim-time`), while "
                        f"{cfg.source} runs on the wall clock: set [ros] use_sim_time = true", EXIT_INPUT))
    elif cfg.ros["use_sim_time"] and not simulated:
        out.append(fail(f"{name} clock", f"stamped on the wall clock while {cfg.source} says [ros] use_sim_time = "
                        "true: set it false for a console (or start `rig sim --sim-time`)", EXIT_INPUT))
    st = arm.operating_state()
    if st is None:
        why = arm.states_error or "none heard, and its operating_state service did not answer"
        out.append(fail(f"{name} state", f"{arm.topic['operating_state']}: {why}; a dVRK 2.2+ console publishes it: "
                        "without it the procedures cannot enable or home the arm"))
    elif st.state == "FAULT":
        out.append(fail(f"{name} state", f"FAULT ({arm._last_error() or 'no message on error'}): clear it at the "
                        "dVRK console (power it off and on, or restart `rig sim`)"))
    else:
        out.append(ok(f"{name} state", st.describe() + ("" if st.ready else ": the procedures enable and home it")))
    problem = arm.servo_ci_problem()
    if problem is None:
        out.append(ok(f"{name} servo_ci", f"{arm.namespace}/servo_ci subscribed by "
                      f"{', '.join(arm.servo_ci_subscribers())}"))
    else:
        out.append(fail(f"{name} servo_ci", f"{problem}; `rig cooperative` refuses it: start a dVRK 2.2+ console "
                        "(or `rig sim` without --no-servo-ci), or run cooperative with --slave-control effort"))
    return out


def ros_devices(cfg, timeout: float) -> list[Check]:
    """Every ROS device of the file (the arms' consoles, ROS mocap, `rig sim`'s operator)
    listened to at once for up to `timeout` s, then each checked."""
    from drivers.arm.dvrk_arm import RosArm
    from drivers.common.ros_session import RosSession, domain_text

    names = [n for n, a in cfg.arms.items() if a["driver"] == "ros"]
    simulated = [ok(n, "simulated in-process") for n, a in cfg.arms.items() if a["driver"] == "sim"]
    mocap = cfg.mocap["driver"] == "ros"
    operator = cfg.operator["driver"] == "ros"
    if not (names or mocap or operator):
        return simulated
    session = RosSession("rig_doctor", executor=cfg.ros["executor"])
    try:
        arms = {n: RosArm(session.node, cfg.arms[n]["namespace"], watchdog=max(cfg.arms[n]["watchdog"], 1.0),
                          spin=False, console=cfg.ros["console"], streams=("measured_js",),
                          polled=session.executor_time, control_node=session.control) for n in names}
        tracker = _mocap_tracker(cfg, session, names) if mocap else None
        op = None
        if operator:
            from drivers.operator.driver import RosOperator

            op = RosOperator(session.control, timeout=timeout)
        session.start()
        out: list[Check] = list(simulated)
        # one wait for every arm's first message
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and any(a.stream_age() == float("inf") for a in arms.values()):
            time.sleep(0.02)
        for n, arm in arms.items():
            if arm.stream_age() == float("inf"):
                out.append(fail(f"{n} console", f"no {arm.topic['measured_js']} within {timeout:g} s on {domain_text()}: "
                                "start the dVRK console (or `rig sim`) there, or set this terminal's ROS_DOMAIN_ID "
                                "(and ROS_AUTOMATIC_DISCOVERY_RANGE) to the console's"))
                continue
            # the rate from the stamps of a few dozen messages, the state from its event or service
            arm.wait_newer(arm.received + 32, min(2.0, timeout))
            arm.wait_for_state(min(2.0, timeout))
            out.extend(arm_checks(cfg, arm, n))
        heard = [a for a in arms.values() if a.stream_age() != float("inf")]
        if heard:
            out.append(_console_topics(heard[0], cfg))
        if tracker is not None:
            out.extend(_mocap_checks(cfg, tracker, timeout))
        if op is not None:
            from drivers.operator.driver import REQUEST_TOPIC

            if op.wait_for_server(min(2.0, timeout)):
                out.append(ok("operator", f"`rig sim`'s simulated person listens on {REQUEST_TOPIC}"))
            else:
                out.append(fail("operator", f"nobody serves {REQUEST_TOPIC} on {domain_text()}: start `rig sim`, or "
                                f"set [operator] driver = 'console' in {cfg.source} for a person at this terminal"))
        return out
    finally:
        session.stop()
        session.close()


def _console_topics(arm, cfg) -> Check:
    """The console's power and home topics (/system: dVRK 2.4, /console: 2.3)."""
    ns = arm.console_namespace()
    names = {n for n, _ in arm.node.get_topic_names_and_types()}
    if f"{ns}/power_on" in names:
        return ok("console topics", f"{ns}/power_on, {ns}/home (dVRK {'2.4' if ns == '/system' else '2.3'})"
                  + (f"; [ros] console = {cfg.ros['console']!r}" if cfg.ros["console"] != "auto" else ""))
    return fail("console topics", f"no {ns}/power_on in the ROS graph: the console's ROS bridge does not serve its "
                "power and home topics; set [ros] console (\"/system\" for dVRK 2.4, \"/console\" for 2.3) or "
                "power and home the arms at the console", EXIT_INPUT)


def _mocap_tracker(cfg, session, names):
    from drivers.mocap.ros_tracker import RosMocapTracker
    from rig.sim.world import default_marker_bodies

    arms = names or list(cfg.arms)
    bodies = [mb.name for n in arms for mb in default_marker_bodies(n)]
    return RosMocapTracker(session.node, bodies, prefix=cfg.mocap["prefix"], stale_timeout=1e9,
                           polled=session.executor_time)


def _mocap_checks(cfg, tracker, timeout: float) -> list[Check]:
    """Every body heard, at what rate, and whether its frames are whole (one stamp for all
    the bodies of a camera frame: what the procedures pair)."""
    from drivers.common.ros_session import domain_text

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and any(n == 0 for n in tracker.stats.received.values()):
        time.sleep(0.02)
    frames0, incomplete0 = tracker.stats.frames, tracker.stats.incomplete
    time.sleep(min(1.0, timeout))  # a window of frames
    tracker.flush_pending()
    tracker.frames()
    out = []
    silent = [b for b, n in tracker.stats.received.items() if n == 0]
    if silent:
        fix = ("start the mocap bridge on this domain, with [mocap] prefix its topics' (`ros2 topic list` on "
               "the bridge's PC)" if len(silent) == len(tracker.bodies) else
               "define them in Motive (named exactly so) and check that the bridge streams them")
        out.append(fail("mocap", f"{len(silent)} of {len(tracker.bodies)} bodies not streamed within {timeout:g} s on "
                        f"{domain_text()}: {', '.join(tracker.topics[b] for b in silent[:4])}"
                        + (" ..." if len(silent) > 4 else "") + f": {fix}"))
    heard = [b for b in tracker.bodies if b not in silent]
    if heard:
        rates = [tracker.rate(b) for b in heard]
        want = float(cfg.mocap["rate"])
        text = f"{len(heard)} bodies at {min(rates):.0f}-{max(rates):.0f} Hz"
        if min(rates) < 0.6 * want:
            out.append(fail("mocap rate", f"{text}; [mocap] rate is {want:g} Hz: set Motive's frame rate (or [mocap] "
                            f"rate = {min(rates):.0f} in {cfg.source})"))
        else:
            out.append(ok("mocap rate", text))
        frames = tracker.stats.frames - frames0
        incomplete = tracker.stats.incomplete - incomplete0
        if frames and not silent and incomplete > 0.5 * frames:
            out.append(fail("mocap frames", f"{incomplete} of {frames} frames lack a body: the bridge must stamp a "
                            "camera frame's bodies with the same time (the frame's), not each on its arrival"))
        elif frames:
            out.append(ok("mocap frames", f"{frames - incomplete} of {frames} frames whole in {min(1.0, timeout):g} s"))
    return out
