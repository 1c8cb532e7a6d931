"""The dVRK arm's operating state as the driver (drivers.arm.dvrk_arm.RosArm) keeps it: the state
asked of the console and waited for, the state commands (enable, home), the faults an arm
that no longer obeys raises (drivers.arm.crtk.ArmFault), and the console it belongs to. A mixin
of RosArm: the state it reads is made in RosArm.__init__."""

from __future__ import annotations

import time

import numpy as np

from drivers.arm.crtk import STATE_COMMANDS, ArmFault, OperatingState
from drivers.arm.dvrk_arm_streams import _stamp_seconds

#: s between repeats of a state command while `ready()` waits (one sent before the
#: arm's subscription matched would be lost; enable and home are idempotent on the dVRK)
RESEND = 1.0


class ArmOperatingState:
    """RosArm's operating state and console (see the module docstring)."""

    # -- operating state ----------------------------------------------------------------
    def operating_state(self) -> OperatingState | None:
        """The newest operating_state (None before the first, or when states are not read)."""
        with self._lock:
            return self._state

    def wait_for_state(self, timeout: float) -> bool:
        """Block until an operating_state arrived (True) or `timeout` s passed (False). The
        dVRK publishes it on change only: the arm's operating_state service is asked too."""
        tb = self._time
        deadline = tb.now() + timeout
        asked = -1.0
        with self._cond:
            while self._state is None:
                now = tb.now()
                left = deadline - now
                if left <= 0 or self._StringStamped is None:
                    return False
                if now - asked >= 0.25:
                    asked = now
                    self._cond.release()
                    try:
                        self._ask_state()
                    finally:
                        self._cond.acquire()
                    continue
                tb.wait(self._cond, min(left, 0.05))
        return True

    def confirm_state(self, timeout: float) -> OperatingState | None:
        """Ask the arm's operating_state service and wait up to `timeout` s for its answer;
        the newest state then (None when none came). The dVRK publishes operating_state on
        change only, and an event sent just now may still be on its way: a run that ends on
        another device's fault asks before it says an arm is held."""
        with self._lock:
            asked_after = self.state_answers
        if not self._ask_state():
            return self.operating_state()
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self.state_answers == asked_after:
                left = deadline - tb.now()
                if left <= 0:
                    break
                tb.wait(self._cond, left)
            return self._state

    def _ask_state(self) -> bool:
        """Ask the arm's operating_state service (asynchronously; the answer is taken as an
        operating_state message when it comes). False when there is no service to ask."""
        client = self._state_client
        if client is None or not client.service_is_ready():
            return False
        from crtk_msgs.srv import TriggerOperatingState

        future = client.call_async(TriggerOperatingState.Request())
        future.add_done_callback(self._on_state_answer)
        return True

    def _on_state_answer(self, future) -> None:
        try:
            res = future.result()
        except Exception:  # noqa: BLE001 - the service went away: the topic will tell
            return
        if res is None:
            return
        with self._lock:
            newer = self._state is None or _stamp_seconds(res.operating_state.header) > self._state.t
        if newer:
            self._on_operating_state(res.operating_state)
        with self._cond:
            self.state_answers += 1
            self._cond.notify_all()

    def state_command(self, command: str) -> None:
        """Send one of STATE_COMMANDS on state_command (asynchronous, as on the dVRK)."""
        if command not in STATE_COMMANDS:
            raise ValueError(f"state command must be one of {', '.join(STATE_COMMANDS)}, got {command!r}")
        if self._StringStamped is None:
            raise RuntimeError(f"{self.topic['state_command']}: operating states are off ({self.states_error})")
        m = self._StringStamped()
        self._stamp(m.header)
        m.string = command
        self._send(self._state_command, m)

    def ready(self, timeout: float = 20.0, say=None) -> OperatingState:
        """Enable and home the arm (state_command `enable`, then `home`, each repeated every
        RESEND s while it has not moved on) and wait until it is ENABLED, homed and not
        busy; from then on leaving that state is a fault (see the module docstring).

        An arm in FAULT or PAUSED is left so: that is a person's call at the console.
        Raises ArmFault (one line: the state seen and the arm's last error) on FAULT,
        PAUSED or when `timeout` s pass. `say(line)`, if given, hears each command sent.
        """
        tb = self._time
        deadline = tb.now() + timeout
        with self._lock:
            self._in_control = False
            self._fault = self._fault_error = None
        sent: dict[str, float] = {}
        while True:
            # (no staleness check here: a stall of the controller while it homes is no fault
            # of a run that has not begun; the run's first measured_js() checks it)
            st = self.operating_state()
            if st is not None:
                if st.state in ("FAULT", "PAUSED"):
                    raise self._not_ready(st, f"is {st.state}" + (
                        "; clear the fault at the dVRK console (disable, then re-run)" if st.state == "FAULT"
                        else "; resume it at the dVRK console, then re-run"))
                if st.ready and not st.is_busy:
                    with self._lock:
                        if self._full is not None and self._index is not None:
                            q = np.asarray(self._full[0], float)
                            self.wrist_hold = q[[i for i in range(len(q)) if i not in self._index]].copy()
                        self._in_control = True
                        self._fault = self._fault_error = None
                        if not self._state.ready:  # it changed since
                            self._fault = self._state
                    return st
                want = None
                if st.state == "DISABLED" and not st.is_busy:
                    want = "enable"
                elif st.state == "ENABLED" and not st.is_homed and not st.is_busy:
                    want = "home"
                if want is not None and tb.now() - sent.get(want, -RESEND) >= RESEND:
                    if say is not None and want not in sent:
                        say(f"{self.name}: {want}")
                    self.state_command(want)
                    sent[want] = tb.now()
            elif tb.now() - sent.get("ask", -RESEND) >= 0.25:
                self._ask_state()  # events only: ask what the state is
                sent["ask"] = tb.now()
            now = tb.now()
            if now >= deadline:
                raise self._not_ready(st, f"not ENABLED and homed within {timeout:g} s"
                                      + ("" if st is None else f" ({st.describe()})")
                                      + "; check the dVRK console (power, e-stop, homing) or `rig sim`")
            with self._cond:
                tb.wait(self._cond, min(deadline - now, 0.05))

    def _last_error(self, within: float = 2.0, locked: bool = False) -> str:
        """The arm's newest error message if it came within `within` s, else ""."""
        if locked:  # the caller holds the lock
            err = self._error
        else:
            with self._lock:
                err = self._error
        return err[1] if err is not None and self._time.now() - err[0] <= within else ""

    def _not_ready(self, st: OperatingState | None, what: str) -> ArmFault:
        error = self._last_error()
        seen = "no operating_state received" if st is None else ""
        text = f"{self.topic['operating_state']}: {self.name} {what}"
        if seen:
            text += f" ({seen})"
        if error:
            text += f"; its last error: {error}"
        return ArmFault(text, self.topic["operating_state"], st, error, arm=self.name)

    def _fault_raised(self, st: OperatingState) -> ArmFault:
        """The ArmFault for a run whose arm left ENABLED and homed (composed once)."""
        if self._fault_error is not None:
            return self._fault_error
        if st.state == "FAULT":  # its error message may come just after the state
            tb = self._time
            until = tb.now() + 0.25
            with self._cond:
                while not self._last_error(locked=True) and tb.now() < until:
                    tb.wait(self._cond, until - tb.now())
        error = self._last_error()
        what = {"FAULT": "went to FAULT", "DISABLED": "was disabled", "PAUSED": "was paused"}.get(
            st.state, f"went to {st.state}") if st.state != "ENABLED" else "was unhomed"
        text = (f"{self.topic['operating_state']}: {self.name} {what} during the run ({st.describe()})"
                + (f": {error}" if error else "") + "; it no longer obeys commands. Check the arm at the dVRK "
                "console (or `rig sim`), then re-run")
        self._fault_error = ArmFault(text, self.topic["operating_state"], st, error, arm=self.name)
        return self._fault_error

    # -- console ------------------------------------------------------------------------
    def _set_console(self, namespace: str) -> None:
        self._console = namespace
        self.topic["power_on"] = f"{namespace}/power_on"
        self.topic["home"] = f"{namespace}/home"

    def _console_publishers(self) -> None:
        for key in ("power_on", "home"):
            self._pubs[key] = self.node.create_publisher(self._Empty, self.topic[key], self._command_qos)

    def console_namespace(self) -> str:
        """The console's namespace; with console="auto", found from the ROS graph: "/system"
        when /system/power_on exists (dVRK 2.4), "/console" when /console/power_on does
        (2.3), and "/console" if neither shows within 2 s."""
        if self._console == "auto":
            # the graph fills in as discovery goes on: look for up to 2 s
            found, deadline = None, time.monotonic() + 2.0
            while found is None and time.monotonic() < deadline:
                names = [n for n, _ in self.node.get_topic_names_and_types()]
                # the power topic itself: a 2.4 system has /console/teleop/... too
                found = next((ns for ns in ("/system", "/console") if f"{ns}/power_on" in names), None)
                if found is None:
                    time.sleep(0.05)
            self._set_console(found or "/console")
            self._console_publishers()
        return self._console

    def power_on(self) -> None:
        self.console_namespace()
        self._send(self._pubs["power_on"], self._Empty())

    def home(self) -> None:
        """Ask the console to home the arms (asynchronous, as on the dVRK)."""
        self.console_namespace()
        self._send(self._pubs["home"], self._Empty())

    def wait_for_subscribers(self, timeout: float = 5.0) -> bool:
        """Block until every command topic has a subscriber (the controller is there);
        servo_ci not counted (a dVRK before 2.2 has none)."""
        deadline = time.monotonic() + timeout
        while any(p.get_subscription_count() == 0 for k, p in self._pubs.items() if k != "servo_ci"):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True
