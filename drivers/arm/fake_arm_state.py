"""The dVRK arm's operating state, emulated: what `rig sim` serves beside each arm.

`FakeArmState` is the far end of the arm driver's state handling (`drivers.arm.dvrk_arm_state`):
it puts a served arm (the console's PSM `drivers.arm.fake_psm.FakePSM` in `rig sim`, or the
in-process `drivers.arm.sim.SimArm` in tests) behind the state machine of a dVRK arm
(sawIntuitiveResearchKit's arm component, as its documentation and messages describe it), on
the simulated clock:

* It starts DISABLED, not homed. `enable` powers the arm (DISABLED and busy for POWERING s,
  then ENABLED). `home` (accepted DISABLED or ENABLED, as on the dVRK) enables it if need
  be, then homes it: a move to its home position (the simulated arm's q0) that takes at
  least HOMING s, busy meanwhile, then is_homed; an arm already homed stays where it is.
  `disable` goes to DISABLED (is_homed stays, as on the dVRK), `unhome` clears is_homed,
  `pause` / `resume` go to PAUSED and back; from FAULT only `disable` leads out. A command
  the state does not allow is refused with the dVRK's words (`command "home" is not
  supported in state "FAULT"`).
* servo_jp, servo_jf and move_jp are obeyed only when ENABLED and homed; the others are
  dropped with the dVRK's warning `<arm>: <command>, arm not ready`, at most once every
  NOT_READY_PERIOD s, with `(N errors)` counting the ones dropped before it since the arm
  was last ready, once there are more than one.
* is_busy is true while powering, while homing, and from a move (move_jp, move_jr,
  move_cp, jaw/move_jp) until its trajectory reached its goal: the set-point, as the
  dVRK's Reflexxes final state; the joints settle on it afterwards under the PID.
  `events` holds an OperatingState for every change and every accepted state command
  (the dVRK publishes operating_state as events, not periodically).
* Faults: a joint past its Table 4.2 limit (beyond LIMIT_MARGIN) while the arm is powered;
  and, once armed (`servo_watchdog`, s), servo commands that stop arriving: an arm in
  servo mode (its last command servo_jp or servo_jf) with none for longer than that; and a
  power loss of its amplifiers (`lose_power`, injected by a test). The arm goes to FAULT,
  not busy, with its reason on <arm>/error.

Without power (DISABLED, FAULT) and PAUSED the simulated arm's joints are held where they
are. The simulated world has no hard stops: a PSM without power would fall through them,
taking the object with it; the real arm's drives are off and its joints rest on their
friction and counterweights.

`command()` and `servo_jp()` ... are called by rig sim's main thread as the messages are
applied, `step(t)` once per tick; the server publishes `events` (and empties it), and
`messages` holds the
(level, text) pairs to send on <arm>/warning and <arm>/error.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.arm.crtk import OperatingState
from rig.model import psm_kinematics as K

#: s the drives take to power on after `enable`
POWERING = 0.25
#: s a homing takes at least (drives on, encoders checked, the move to the home position)
HOMING = 1.5
#: s a homing may take before the arm faults
HOMING_TIMEOUT = 10.0
#: s between two "arm not ready" warnings (the dVRK's throttle)
NOT_READY_PERIOD = 2.0
#: rad, rad, m beyond the joint limits at which a powered arm faults
LIMIT_MARGIN = np.array([0.01, 0.01, 0.002])

# the dVRK's allowed state commands per operating state (prmOperatingState::ValidCommand);
# in DISABLED the dVRK also accepts home and pause (its switch falls through to ENABLED)
_ALLOWED = {
    "DISABLED": {"enable", "disable", "unhome", "home", "pause"},
    "ENABLED": {"enable", "disable", "pause", "unhome", "home"},
    "PAUSED": {"disable", "pause", "resume", "unhome"},
    "FAULT": {"disable", "unhome"},
}


class FakeArmState:
    """A served arm behind the dVRK's operating state (see the module docstring).

    arm: the FakePSM (or SimArm); limits: the joint limits whose crossing faults the arm (Table 4.2);
    servo_watchdog: s without a servo command, in servo mode, before the arm faults (None:
    no watchdog, as a dVRK's ROS interface has none of its own).
    """

    def __init__(self, arm, limits: K.JointLimits | None = None, servo_watchdog: float | None = None):
        self.arm = arm
        self.name = arm.name
        self.limits = limits or K.JointLimits()
        self.servo_watchdog = servo_watchdog
        self.state = "DISABLED"
        self.is_homed = False
        self.is_busy = False
        #: every change of (state, is_homed, is_busy) and every accepted state command, in
        #: order, for the server to publish one operating_state each (the dVRK's events)
        self.events: list[OperatingState] = [OperatingState(0.0, self.state, self.is_homed, self.is_busy)]
        self.messages: list[tuple[str, str]] = []
        self.dropped = 0  # motion commands dropped (not ready)
        self.fault_reason = ""
        self._t = 0.0
        self._powering_until: float | None = None
        self._home_wanted = False
        self._homing_since: float | None = None
        self._move_ended: float | None = None  # when the current move_jp's trajectory ended
        self._moving = False
        self._servo_mode = False
        self._last_servo = -math.inf
        self._not_ready_count = 0
        self._not_ready_last = -math.inf
        self._sl = arm.world.arms[arm.name].sl
        self._low = self.limits.q_min - LIMIT_MARGIN  # the limit check runs every step
        self._high = self.limits.q_max + LIMIT_MARGIN
        arm.hold()  # not powered: held where it is (see the module docstring)

    # -- what rig sim publishes ---------------------------------------------------------
    def operating_state(self) -> OperatingState:
        return OperatingState(self._t, self.state, self.is_homed, self.is_busy)

    @property
    def ready(self) -> bool:
        return self.state == "ENABLED" and self.is_homed

    def _set(self, state: str | None = None, busy: bool | None = None, homed: bool | None = None) -> None:
        changed = False
        for attr, value in (("state", state), ("is_homed", homed), ("is_busy", busy)):
            if value is not None and getattr(self, attr) != value:
                setattr(self, attr, value)
                changed = True
        if changed:
            self.events.append(self.operating_state())
            if hasattr(self.arm, "homed"):
                self.arm.homed = self.is_homed

    def _say(self, level: str, text: str) -> None:
        self.messages.append((level, text))

    # -- state commands -------------------------------------------------------------------
    def command(self, command: str, t: float) -> None:
        """A state_command (enable, disable, home, unhome, pause, resume) at sim time t."""
        self._t = t
        if command not in _ALLOWED.get(self.state, ()):
            self._say("warning", f"{self.name}: command \"{command}\" is not supported in state \"{self.state}\"")
            return
        # the dVRK pushes its operating state on every valid command (SetDesiredState's
        # StateEvents): a client that just connected learns the state from its own command
        self.events.append(self.operating_state())
        if command == "enable":
            self._power_on(t)
        elif command == "disable":
            self._power_off()
            self._set(state="DISABLED", busy=False)
        elif command == "home":
            self._home_wanted = True
            if self.state == "DISABLED":
                self._power_on(t)
            elif self._powering_until is None:
                self._start_homing(t)
        elif command == "unhome":
            self._homing_since = None
            self._home_wanted = False
            self._set(homed=False, busy=False if self._powering_until is None else None)
        elif command == "pause":
            self._stop_motion()
            self._powering_until = self._homing_since = None
            self._set(state="PAUSED", busy=False)
        elif command == "resume":
            self._set(state="ENABLED")

    def _power_on(self, t: float) -> None:
        if self.state == "ENABLED" or self._powering_until is not None:
            return
        self._powering_until = t + POWERING
        self._set(busy=True)

    def _power_off(self) -> None:
        self._stop_motion()
        self._powering_until = self._homing_since = None
        self._home_wanted = False

    def _stop_motion(self) -> None:
        self.arm.hold()
        self._moving = False
        self._move_ended = None
        self._servo_mode = False

    def _start_homing(self, t: float) -> None:
        self._home_wanted = False
        if self.is_homed or self._homing_since is not None:
            return  # the dVRK keeps a homed arm where it is; a homing under way goes on
        self._homing_since = t
        self._servo_mode = False
        self.arm.move_jp(self.arm.home_position, wait=False)
        self._set(busy=True)

    # -- motion commands ----------------------------------------------------------------
    def _accept(self, what: str, t: float) -> bool:
        self._t = t
        if self.ready:
            self._not_ready_count = 0
            self._not_ready_last = -math.inf
            return True
        self.dropped += 1
        if t - self._not_ready_last > NOT_READY_PERIOD:
            n = self._not_ready_count  # dropped since the arm was last ready, before this one
            self._say("warning", f"{self.name}: {what}, arm not ready" + (f" ({n} errors)" if n > 1 else ""))
            self._not_ready_last = t
        self._not_ready_count += 1
        return False

    def servo_jp(self, position, velocity, t: float) -> bool:
        if not self._accept("servo_jp", t):
            return False
        self.arm.servo_jp(position, velocity)
        self._servo(t)
        return True

    def servo_jf(self, effort, t: float) -> bool:
        if not self._accept("servo_jf", t):
            return False
        self.arm.servo_jf(effort)
        self._servo(t)
        return True

    def _servo(self, t: float) -> None:
        self._servo_mode = True
        self._last_servo = t
        self._moving = False
        self._move_ended = None
        self._set(busy=False)

    def move_jp(self, position, t: float) -> bool:
        return self.motion("move_jp", t, lambda: self.arm.move_jp(position, wait=False), moving=True)

    def motion(self, what: str, t: float, act, moving: bool = False, servo: bool = True) -> bool:
        """A motion command `what` at sim time t: `act()` runs if the arm is ready (True),
        else it is dropped with the dVRK's throttled warning (False). `moving`: it starts a
        trajectory (busy until it ends; an act returning False started none); `servo`: a
        servo command (it counts for the servo watchdog and ends a move). A ValueError of
        `act` (a malformed command) propagates."""
        if not self._accept(what, t):
            return False
        started = act()
        if moving:
            self._servo_mode = False
            if started is False:
                return True
            self._moving = True
            self._move_ended = None
            # (the dVRK's UpdateIsBusy(true): an event even when busy already, a new move)
            if self.is_busy:
                self.events.append(self.operating_state())
            self._set(busy=True)
        elif servo:
            self._servo(t)
        return True

    # -- faults ---------------------------------------------------------------------------
    def fault(self, reason: str) -> None:
        """Go to FAULT (the drives off; here: held), with `reason` on <arm>/error."""
        self._power_off()
        self.fault_reason = reason
        self._say("error", reason)
        self._set(state="FAULT", busy=False)

    def lose_power(self) -> None:
        """The arm's amplifiers lose power where it stands: FAULT with the dVRK's "detected
        power loss (actuators)". Only a powered arm notices (the dVRK checks the amplifiers'
        status while powered); a DISABLED or FAULT arm is left as it is."""
        if self.state in ("ENABLED", "PAUSED") or self._powering_until is not None:
            self.fault(f"{self.name}: detected power loss (actuators)")

    def push_past_limit(self, joint: int = 1) -> None:
        """A person pushes joint `joint` (1-3) of the arm past its upper limit (2 margins
        beyond): the limit check faults a powered arm at the next step."""
        if joint not in (1, 2, 3):
            raise ValueError(f"joint must be 1, 2 or 3, got {joint}")
        world = self.arm.world
        q = world.qm[self._sl].copy()
        q[joint - 1] = self.limits.q_max[joint - 1] + 2.0 * LIMIT_MARGIN[joint - 1]
        world.set_state(self.name, q)
        self.arm.hold()

    # -- the arm's cycle ------------------------------------------------------------------
    def step(self, t: float) -> None:
        """Advance powering, homing, busy and the fault checks to sim time t."""
        self._t = t
        if self._powering_until is not None and t >= self._powering_until:
            self._powering_until = None
            self.arm.hold()
            self._set(state="ENABLED", busy=False)
            if self._home_wanted:
                self._start_homing(t)
        if self.state not in ("ENABLED", "PAUSED") or self._powering_until is not None:
            return
        q = self.arm.world.qm[self._sl]
        low, high = self._low, self._high
        if (q < low).any() or (q > high).any():
            j = int(np.argmax((q < low) | (q > high)))
            unit = "m" if j == 2 else "rad"
            self.fault(f"{self.name}: joint {j + 1} at {q[j]:.4f} {unit}, past its limit "
                       f"[{self.limits.q_min[j]:g}, {self.limits.q_max[j]:g}] {unit}")
            return
        if (self.servo_watchdog is not None and self._servo_mode and self.state == "ENABLED"
                and t - self._last_servo > self.servo_watchdog):
            self.fault(f"{self.name}: watchdog: no servo command for {1e3 * (t - self._last_servo):.0f} ms "
                       f"(limit {1e3 * self.servo_watchdog:.0f} ms)")
            return
        if self._homing_since is not None:
            if t - self._homing_since >= HOMING and self.arm.arrived():
                self._homing_since = None
                self._set(homed=True, busy=False)
            elif t - self._homing_since > HOMING_TIMEOUT:
                self.fault(f"{self.name}: homing did not reach the home position in {HOMING_TIMEOUT:g} s")
            return
        if self._moving and not self.arm.is_moving():
            # the dVRK's trajectory reached its final state (the set-point is at the goal):
            # busy ends, whatever the measured joints do next (Reflexxes' FINAL_STATE_REACHED)
            self._moving = False
            self._set(busy=False)
