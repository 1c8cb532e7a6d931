"""The fault matrix over the wire, shared by bench/bench_faults.py and tests/hil/test_fault_matrix.py:
each procedure as a lab runs it, the faults a rig meets, how each is injected into `rig sim`
(tests/hil/harness.py) when the procedure's step begins, and what a clean ending is (issue 37).

* server killed: rig sim SIGKILLed (the arms' console, its load cell and mocap die with it)
* load-cell pty closed, mocap stopped: the simulated person pulls that cable
* operator gone: the simulated person walks away (requests go unanswered)
* arm FAULT: PSM1's amplifiers lose power where it stands (the dVRK's "detected power loss
  (actuators)": an amplifier's fault, its controller's e-stop). Not a push past a joint
  limit: rig sim's push is a jump, and with a spring or string between the arms its pull
  (hundreds of N at 2450 N/m) drags the other arm into a fault of its own, sometimes after
  the procedure has ended; what a run reports is then judged against a moving truth
* SIGINT, SIGTERM: sent to the procedure

A fault that cannot reach the procedure (it does not use that device after the fault)
must leave it ending as if nothing happened ("unused": completed, or failed on its own
figures). Otherwise a cell is clean when
the procedure ends with one line on stderr, no traceback, no signal, the documented exit
(3 aborted; 130 for SIGINT), every arm it moved held (an arm in FAULT obeys nothing: it is
reported not held), and its recording closed with the reason.
"""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass, field

from tests.hil.harness import ServedRig, lab_toml
from tests.ros_domains import ros_environment

#: the operator's answer limit on this rig (s): an operator gone is seen after it. With two
#: CPU burners rig sim answered register's touches later than 5 s (it falls behind the clock)
OPERATOR_TIMEOUT = 15.0


@dataclass
class Procedure:
    args: list[str]
    step: str                  # the fault lands when this step begins (its "... " line)
    arms: list[str]            # the arms it moves
    uses: set[str] = field(default_factory=set)  # devices it reads after the step begins
    three_arms: bool = False   # on the three-arm lab (PSM3 too, a triangle with a cell per element)


PROCEDURES: dict[str, Procedure] = {
    "loadcell-calibrate": Procedure(["loadcell-calibrate", "--seconds", "3"], "average counts with mass 1 ...", [],
                                    {"loadcell", "operator"}),
    "link-lengths": Procedure(["link-lengths", "--q1-range", "0.5", "--q2-range", "0.4", "--passes", "1",
                               "--q3-stroke", "0.05"], "sweep q1 with q2 = 0 ...", ["PSM1"], {"arms", "mocap"}),
    "calibrate-rcm": Procedure(["calibrate-rcm", "--arm", "PSM1", "--duration", "6", "--q1-range", "0.5",
                                "--q2-range", "0.4"], "sweep q1 with q2 = 0", ["PSM1"], {"arms", "mocap"}),
    # 10 points: the step lasts long enough for the fault to land inside it on a loaded machine
    "register": Procedure(["register", "--points", "10"], "measure ...", ["PSM1", "PSM2"], {"arms", "operator"}),
    "identify": Procedure(["identify", "--arm", "PSM1", "--duration", "10", "--starts", "1", "--iterations", "5",
                           "--no-plots"], "run the excitation trajectory ...", ["PSM1"], {"arms"}),
    "friction-ramp": Procedure(["friction-ramp", "--arm", "PSM1", "--ramp-time", "1.5", "--speeds", "0.01,0.02,0.04",
                                "--no-plots"], "force ramp, positive direction ...", ["PSM1"], {"arms"}),
    "cooperative": Procedure(["cooperative", "--force", "5", "--object", "spring", "--move", "0.02,0,0", "--duration",
                              "4", "--settle", "1", "--hold-after", "0"], "hold the tension while moving ...",
                             ["PSM1", "PSM2"], {"arms", "loadcell"}),
    "cooperative-string": Procedure(["cooperative", "--force", "5", "--object", "string", "--move", "0.02,0,0",
                                     "--duration", "4", "--settle", "1", "--hold-after", "0"],
                                    "hold the tension while moving ...", ["PSM1", "PSM2"], {"arms", "loadcell"}),
    "cooperative-triangle": Procedure(["cooperative", "--force", "5", "--arms", "PSM1,PSM2,PSM3", "--object", "spring",
                                       "--move", "0.02,0,0", "--duration", "4", "--settle", "1", "--hold-after", "0"],
                                      "hold the tension while moving ...", ["PSM1", "PSM2", "PSM3"],
                                      {"arms", "loadcell"}, three_arms=True),
}

#: fault -> (the device it takes away: "any" for all of them, None for a signal; the exit code;
#: whether rig sim is left broken after it)
FAULTS = {
    "server killed": ("any", 3, True),  # rig sim serves every device: the arms, the cell's pty, mocap, the operator
    "load-cell pty closed": ("loadcell", 3, True),
    "mocap stopped": ("mocap", 3, True),
    "operator gone": ("operator", 3, True),
    "arm FAULT": ("arms", 3, True),
    "SIGINT": (None, 130, False),
    "SIGTERM": (None, 3, False),
}


class _Person:
    """The simulated person's side channel, opened before the procedure starts so that a
    fault lands at once when its step begins (opening a ROS session and finding rig sim
    takes a second or more: longer than some steps, e.g. register's touches)."""

    def __init__(self, domain: int):
        from drivers.operator.driver import RosOperator
        from drivers.common.ros_session import RosSession

        self._env = ros_environment(domain)
        self._env.__enter__()
        self.session = RosSession("bench_person")
        self.session.start()
        self.operator = RosOperator(self.session.control, timeout=10.0)
        self.operator.wait_for_server(10.0)
        #: every arm's error messages while the person watched: (arm, text)
        self.errors: list[tuple[str, str]] = []

    def watch_errors(self, arms) -> None:
        """Hear each arm's <arm>/error (why an arm faulted, for the table)."""
        from std_msgs.msg import String

        for arm in arms:
            self.session.control.create_subscription(
                String, f"/{arm}/error", lambda m, a=arm: self.errors.append((a, m.data)), 10)

    def states(self, arms, timeout: float = 5.0) -> dict[str, str]:
        """Each arm's operating state as rig sim answers it now ("FAULT, homed", ...; "?"
        when it did not answer): the truth a run's "held" is judged against."""
        from crtk_msgs.srv import TriggerOperatingState

        from drivers.arm.crtk import OperatingState

        out = {}
        for arm in arms:
            client = self.session.control.create_client(TriggerOperatingState, f"/{arm}/operating_state")
            try:
                if not client.wait_for_service(timeout_sec=timeout):
                    out[arm] = "?"
                    continue
                future = client.call_async(TriggerOperatingState.Request())
                deadline = time.monotonic() + timeout
                while not future.done() and time.monotonic() < deadline:
                    time.sleep(0.01)
                m = future.result().operating_state if future.done() else None
                out[arm] = "?" if m is None else OperatingState(0.0, m.state, m.is_homed, False).describe()
            finally:
                self.session.control.destroy_client(client)
        return out

    def close(self) -> None:
        try:
            self.session.close()
        finally:
            self._env.__exit__(None, None, None)


#: fault -> what the person does (faults of the procedure's process are signals, not in here)
_BY_PERSON = {
    "load-cell pty closed": lambda op: op.unplug("loadcell"),
    "mocap stopped": lambda op: op.unplug("mocap"),
    "operator gone": lambda op: op.unplug("operator"),
    "arm FAULT": lambda op: op.fault("PSM1", "power_loss"),
}


def _inject(rig: ServedRig, fault: str, proc_box: list, person: _Person | None) -> None:
    if fault == "server killed":
        rig.kill(signal.SIGKILL)
    elif fault in _BY_PERSON:
        _BY_PERSON[fault](person.operator)
    elif fault == "SIGINT":
        proc_box[0].send_signal(signal.SIGINT)
    elif fault == "SIGTERM":
        proc_box[0].send_signal(signal.SIGTERM)


def cell(rig: ServedRig, name: str, fault: str) -> dict:
    """Run one procedure with one fault; what happened."""
    from rig.runs.recording import read_recording

    p = PROCEDURES[name]
    device, code, _ = FAULTS[fault]
    box: list = [None]
    t_fault: list[float] = []

    person = _Person(rig.domain) if fault in _BY_PERSON else None
    if fault == "arm FAULT":
        person.watch_errors(p.arms)

    def fire() -> None:
        t_fault.append(time.monotonic())
        try:
            _inject(rig, fault, box, person)
        except Exception as exc:  # noqa: BLE001 - reported in the cell
            t_fault.append(-1.0)
            print(f"    injecting {fault}: {type(exc).__name__}: {exc}", flush=True)

    truth: dict[str, str] = {}
    try:
        out = rig.run(*p.args, on_start=lambda proc: box.__setitem__(0, proc), when=(p.step, fire))
        if fault == "arm FAULT":
            truth = person.states(p.arms)
    finally:
        if person is not None:
            person.close()
    t_end = time.monotonic()
    doc = out.doc or {}
    unused = device not in (None, "any") and device not in p.uses
    problems = []
    if out.code < 0:
        problems.append(f"signal {-out.code}")
    if "Traceback" in out.stderr or "Fatal Python error" in out.stderr:
        problems.append("traceback")
    if not t_fault:
        problems.append("the step never began")
    status = doc.get("status", "?")
    if unused:
        # the run's own verdict stands (completed, or failed on its figures: exit 4)
        if out.code not in (0, 4):
            problems.append(f"a fault of an unused device ended it: exit {out.code}")
    else:
        if out.code != code:
            problems.append(f"exit {out.code}, not {code}")
        if not out.last_line.startswith(f"rig {p.args[0]}: aborted: "):
            problems.append("last line")
        held = sorted(doc.get("held") or [])
        # an arm in FAULT obeys nothing: PSM1 here, and an arm the object dragged into a
        # fault of its own (a string's pull past a limit). Judged by rig sim's own answer
        # after the run: those must be reported not held, with their state; the rest held.
        faulted = {a for a, st in truth.items() if not st.startswith("ENABLED, homed")}
        moved = sorted(a for a in p.arms if a not in faulted)
        if held != moved:
            problems.append(f"held {held}, moved and obeying {moved}" + (f" (rig sim: {truth})" if truth else ""))
            problems += [f"{a} said: {text}" for a, text in person.errors] if person else []
        reported = {e.get("arm"): e.get("state", "") for e in doc.get("hold_errors") or []}
        for a in sorted(faulted):
            if not reported.get(a, "").startswith(truth[a].split(",")[0]):
                problems.append(f"{a} is {truth[a]} in rig sim, reported {reported.get(a) or 'nothing'}")
    rec_status = "-"
    if doc.get("run_dir"):
        rec = read_recording(os.path.join(doc["run_dir"], "run.mcap"))
        rec_status = (rec.stop or {}).get("status", "no stop record") if rec.finalised else "not finalised"
        if not unused and (not rec.finalised or rec.stop is None or rec.stop.get("status") != "aborted"
                           or not rec.stop.get("error")):
            problems.append(f"recording {rec_status}")
    elif not unused:
        problems.append("no run folder")
    return {"ok": not problems, "problems": problems, "unused": unused, "status": status, "line": out.last_line,
            "held": doc.get("held") or [], "recording": rec_status,
            "detect_s": (t_end - t_fault[0]) if t_fault and t_fault[0] > 0 else None}




def lab(folder, three_arms: bool = False) -> str:
    """The matrix's rig.toml: the chain's (`three_arms`: with PSM3 and a triangle), the
    operator's answer limit OPERATOR_TIMEOUT."""
    return (lab_toml(folder, three_arms=three_arms, rate=500.0 if three_arms else None)
            + f"timeout = {OPERATOR_TIMEOUT}\n")  # in its [operator] table


def sim_args(three_arms: bool = False) -> tuple[str, ...]:
    """rig sim's options for the lab: 500 Hz streams; three arms at a 500 Hz servo too (its
    default with three is 250 Hz, and cooperative refuses a triangle below 500 Hz streams)."""
    return (("--rate", "500") if three_arms else ()) + ("--ros-period", "0.002")


def prepare(rig: ServedRig, three_arms: bool = False) -> str | None:
    """What the lab's procedures need in its logs; None, or the line of what failed. The
    two-arm lab: the load cell calibrated, the arms registered, PSM1 identified and
    friction-ramped; the three-arm lab: each element's cell calibrated, the arms registered,
    every arm identified (cooperative runs each arm on its own identified model)."""
    ident = list(PROCEDURES["identify"].args)
    arm_at = ident.index("--arm") + 1

    def identify(arm: str) -> tuple:
        return tuple(ident[:arm_at] + [arm] + ident[arm_at + 1:])

    if three_arms:
        steps = [("loadcell-calibrate", "--seconds", "0.5", "--element", str(k)) for k in range(3)]
        steps += [("register", "--points", "6")] + [identify(a) for a in ("PSM1", "PSM2", "PSM3")]
    else:
        steps = [("loadcell-calibrate", "--seconds", "0.5"), ("register", "--points", "6"),
                 identify("PSM1"), identify("PSM2"), tuple(PROCEDURES["friction-ramp"].args)]
    for what in steps:
        out = rig.run(*what)
        if out.code:
            return f"{what[0]}: {out.last_line}"
    return None
