"""The time a process's ROS drivers wait and age on: the wall clock, or a simulator's /clock in lockstep.

Against a real dVRK console every wait, timeout and stream age is on this host's clock
(`WallTime`). Against `rig sim --sim-time` they are on the simulator's clock (`SimTime`):
the world's time, published on `/clock` (rosgraph_msgs/Clock) as Gazebo publishes it, and
followed by every process started with ROS's `use_sim_time` (`[ros] use_sim_time = true`).
A loaded machine then runs the world slower than real time and the procedure with it.

Lockstep (docs/simulated-time.md): the simulator does not step past a ROS period until
every process that follows its clock has answered that period, on `ANSWER_TOPIC`
(std_msgs/Header: `stamp` the simulated time answered, `frame_id` "client=<id> sent=<n>
mode=<hold|free|bye> next=<ns>"). `next` is the first period the process will act on
again (a loop slower than the streams lets the world run to it without a round trip for
each period between). `sent` counts the commands this process has published to the
arms and the console, so the simulator applies them before it steps on (DDS keeps no
order between topics; a command may reach it after the answer that follows it). A
process answers in one of two modes:

* hold: its control loop (`rig.devices.clock.SimTimeClock`) answers a period once it has
  acted on that period's samples; the world waits for it, however long it computes.
* free: anywhere else (connecting, waiting for a move, for the operator, between steps)
  its executor thread answers every /clock it receives, so the world runs as fast as the
  process takes its messages, and no faster.

Any wait of a driver (`SimTime.wait`) frees the world; the loop's next tick holds it again.

A simulator that waits for an answer repeats its newest /clock every `HEARTBEAT` s of wall
time (the same stamp: time does not move), and a process that owes no answer but has
nothing to send (free, its load cell's reader held off the CPU; held, its loop computing)
repeats its newest answer as often: each side tells a peer that waits from one that died.
A simulator that stops (killed, unplugged) stops its clock and its repeats, and every age
measured on it with it: `check()` raises `ClockStopped` once neither has come for `stall`
s of wall time while this process was waiting for it (holding it while computing does
not count).
"""

from __future__ import annotations

import os
import struct
import threading
import time

from rig.faults import DeviceFault

#: where the simulator publishes its time (rosgraph_msgs/Clock), as every ROS simulator does
CLOCK_TOPIC = "/clock"
#: where a process in lockstep answers the periods of the simulator's clock (std_msgs/Header)
ANSWER_TOPIC = "/rig_sim/clock_answer"
#: s of wall time, the longest a driver's wait sleeps before it reads the simulated clock again
WAIT_SLICE = 0.02
#: s of simulated time a device read on a thread of its own (a load cell's port) may lag the
#: clock a free process answers: the world waits for its reader too
SYNC_LAG = 0.01
#: s of wall time between two answers of a process that holds the world while it computes
#: (or, free, waits for its load cell's reader): its executor repeats the last one, so the
#: simulator tells a busy process from a dead one; the simulator repeats its /clock as
#: often while it waits for answers (`rig.sim_server.lockstep`)
HEARTBEAT = 0.2
#: s of wall time the clock may stand still while this process waits for it, before the
#: simulator counts as gone (what a process held off the CPU was measured to cost on a busy
#: 2-core machine: the floor of the wall-clock ROS streams' stale limits)
STALL = 2.0

_CLOCK = struct.Struct("<iI")  # builtin_interfaces/Time after the 4-byte CDR encapsulation


class ClockStopped(DeviceFault):
    """The simulator's /clock stood still while this process waited for it."""

    def __init__(self, age: float, stall: float):
        self.topic = CLOCK_TOPIC
        self.age = age
        self.watchdog = stall
        super().__init__(
            f"{CLOCK_TOPIC}: the simulated time stood still for {age:.1f} s of wall time while this process waited "
            f"for it (limit {stall:g} s): `rig sim --sim-time` stopped or was killed; check that it runs on "
            f"{_domain()}, or set [ros] use_sim_time = false for a console on the wall clock")


def _domain() -> str:
    """The ROS domain this process is on, for a line (as drivers.common.ros_session.domain_text says it;
    not imported from there: the session's module imports this one)."""
    scope = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    return f"ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0') or '0'}" + (f", discovery {scope}" if scope else "")


class WallTime:
    """This host's monotonic clock: what a procedure waits on against a real console."""

    simulated = False

    def now(self) -> float:
        return time.monotonic()

    def wait(self, cond: threading.Condition, timeout: float) -> None:
        """Wait on `cond` (held by the caller) for at most `timeout` s."""
        if timeout > 0:
            cond.wait(timeout)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def check(self) -> None:
        """Raise if time itself is gone (never, on the wall clock)."""

    def free(self) -> None:
        """About to wait on something else than a Condition: let time run (and check it)."""

    def stalled(self) -> ClockStopped | None:
        return None

    def sent(self, n: int = 1) -> None:
        """Count commands published (only the lockstep answers need them)."""

    def poll(self) -> None:
        """Called by the executor thread after each wait (only lockstep answers need it)."""

    def notify(self) -> None:
        """A sample arrived (only a loop waiting on simulated time needs to hear it)."""

    def describe(self) -> str:
        return "the wall clock"

    def close(self) -> None:
        pass


def parse_clock(raw: bytes) -> int:
    """ns of a serialized rosgraph_msgs/Clock (raises ValueError on bytes that are not one)."""
    if len(raw) < 4 + _CLOCK.size or raw[1] not in (0, 1):
        raise ValueError("not a rosgraph_msgs/Clock")
    fmt = "<iI" if raw[1] == 1 else ">iI"
    sec, nsec = struct.unpack_from(fmt, raw, 4)
    return sec * 1_000_000_000 + nsec


class SimTime:
    """Simulated time from a simulator's /clock, answered in lockstep (see the module docstring).

    node: the node of the /clock subscription and the answers' publisher (the streams'
    node: a /clock arrives once per ROS period, beside the arms' samples); lockstep: answer
    the periods (False: only follow the clock, as a plain `use_sim_time` node); stall: s
    of wall time (`ClockStopped`); polled: the monotonic time at which the executor last
    looked for messages (`drivers.common.ros_session.RosSession.executor_time`), so that a
    process held off the CPU never takes the simulator for gone.
    """

    simulated = True

    def __init__(self, node, *, lockstep: bool = True, stall: float = STALL, polled=None):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Header

        self.lockstep = bool(lockstep)
        self.stall = float(stall)
        self._polled = polled
        self.client = f"{os.getpid()}-{id(self) & 0xFFFF:04x}"
        self.changed = threading.Condition()
        self._t_ns: int | None = None
        self._advanced = time.monotonic()  # wall time the clock last moved (or we last answered)
        self._repeated = 0.0  # wall time the simulator last repeated its clock (it waits for an answer)
        self._held = False
        self._answered_ns = -1
        self._next_ns = 0  # hold: the first period the loop acts on again
        self._answered_at = 0.0  # wall time of the last answer published
        self._sent = 0
        self._closed = False
        self._lock = threading.Lock()
        self._Header = Header
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        # raw: the stamp is all there is; one a period, beside the arms' streams
        self._sub = node.create_subscription(Clock, CLOCK_TOPIC, self._on_clock, qos, raw=True)
        self._pub = node.create_publisher(Header, ANSWER_TOPIC, qos) if self.lockstep else None
        self._node = node
        #: devices read on threads of their own, with `caught_up(t)` (a load cell): a period
        #: is answered once they have taken what the world wrote up to it
        self.syncs: list = []
        self.clocks = 0  #: /clock messages received
        self.answers = 0  #: answers published

    # -- the clock ----------------------------------------------------------------------
    def _on_clock(self, raw: bytes) -> None:
        try:
            ns = parse_clock(raw)
        except ValueError:
            return
        with self.changed:
            if self._t_ns is not None and ns <= self._t_ns:
                if ns == self._t_ns:
                    self._repeated = time.monotonic()  # it waits for an answer: alive
                return  # a simulator that started over: the clock stands, ClockStopped ends the run
            self._t_ns = ns
            self._advanced = time.monotonic()
            self.clocks += 1
            free = not self._held
            self.changed.notify_all()
        if free:
            self._free_answer()

    def add_sync(self, device) -> None:
        """A device whose reader the world waits for (`caught_up(t)`: a load cell)."""
        self.syncs.append(device)

    def _free_answer(self) -> None:
        """Free mode: answer the newest clock once every sync device has caught up with it."""
        ns = self._t_ns
        if ns is None or self._held or ns <= self._answered_ns:
            return
        t = ns * 1e-9 - SYNC_LAG
        if all(d.caught_up(t) for d in self.syncs):
            self._answer(ns)

    def now(self) -> float:
        """s on the simulator's clock (0.0 before its first /clock)."""
        t = self._t_ns
        return 0.0 if t is None else t * 1e-9

    def now_ns(self) -> int | None:
        return self._t_ns

    def heard(self) -> bool:
        """A /clock has arrived."""
        return self._t_ns is not None

    def wait_heard(self, timeout: float) -> bool:
        """Wait up to `timeout` s of wall time for the first /clock (True once heard)."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while self._t_ns is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(min(left, 0.05))
        return True

    # -- lockstep -----------------------------------------------------------------------
    def _answer(self, ns: int, mode: str | None = None) -> None:
        if self._pub is None:
            return
        with self._lock:
            if (mode is None and ns <= self._answered_ns) or (self._closed and mode != "bye"):
                return  # an answer after bye would make the simulator wait for a process that left
            self._answered_ns = max(self._answered_ns, ns)
            m = self._Header()
            m.stamp.sec, m.stamp.nanosec = divmod(max(ns, 0), 1_000_000_000)
            m.frame_id = (f"client={self.client} sent={self._sent} mode={mode or ('hold' if self._held else 'free')} "
                          f"next={self._next_ns if self._held else 0}")
            self.answers += 1
            self._answered_at = time.monotonic()
            try:
                self._pub.publish(m)
            except Exception:  # noqa: BLE001 - the context is shutting down: nothing left to answer
                pass

    def poll(self) -> None:
        """From the executor thread, after each wait for messages: a process that holds the
        world repeats its last answer every HEARTBEAT s, so that the simulator keeps waiting
        for a procedure that computes and lets go of one that died (it cannot say bye)."""
        if self._closed or self._answered_ns < 0 or time.monotonic() - self._answered_at <= HEARTBEAT:
            return
        if self._held:
            self._answer(self._answered_ns, "hold")
        else:
            self._free_answer()  # the newest clock if the load cells have caught up with it,
            if time.monotonic() - self._answered_at > HEARTBEAT:  # else the last one again
                self._answer(self._answered_ns, "free")

    def hold(self) -> None:
        """From now on the world waits for `answer()` (the control loop's tick)."""
        self._held = True

    @property
    def held(self) -> bool:
        return self._held

    def answer(self, ns: int | None = None, next_ns: int | None = None) -> int:
        """Answer the period at `ns` (default: the newest clock): its samples are acted on and
        the commands for it sent; `next_ns`: the first period the loop acts on again (the
        world need not wait for an answer before it). Returns the period answered (ns; 0
        before the first /clock): a newer one may have come meanwhile."""
        if next_ns is not None:
            self._next_ns = int(next_ns)
        t = self._t_ns if ns is None else ns
        if t is None:
            return 0
        with self.changed:
            self._advanced = max(self._advanced, time.monotonic())
        self._answer(t, "hold" if self._held else None)
        return t

    def release(self) -> None:
        """Free the world: the executor answers every /clock from now on."""
        if self._held:
            self._held = False
            if self._t_ns is not None:
                with self.changed:
                    self._advanced = max(self._advanced, time.monotonic())
                self._free_answer()

    def sent(self, n: int = 1) -> None:
        """Count `n` commands published to the arms or the console (before the answer that follows them)."""
        with self._lock:
            self._sent += n

    def notify(self) -> None:
        """A sample arrived, or a device caught up: wake a loop waiting on it (and, free,
        answer a period that waited for the device)."""
        with self.changed:
            self.changed.notify_all()
        if not self._held and self.syncs:
            self._free_answer()

    # -- waiting ------------------------------------------------------------------------
    def stalled(self) -> ClockStopped | None:
        """ClockStopped if the clock has stood still, and the simulator has not repeated it,
        for `stall` s of wall time while this process waited for it (the executor polling,
        every period answered), else None."""
        if self._t_ns is None or (self.lockstep and self._answered_ns < self._t_ns):
            # not heard yet (connect says so), or the world waits for our answer: our loop's
            # (held), or our load cell's reader's (free), held off the CPU on a loaded machine
            return None
        now = time.monotonic()
        if self._polled is not None:
            now = min(now, self._polled())
        age = now - max(self._advanced, self._repeated)
        return ClockStopped(age, self.stall) if age > self.stall else None

    def check(self) -> None:
        err = self.stalled()
        if err is not None:
            raise err

    def free(self) -> None:
        """About to wait on something else than a Condition (a queue, a port): free the
        world, and raise ClockStopped if the simulator is gone."""
        self.release()
        self.check()

    def wait(self, cond: threading.Condition, timeout: float) -> None:
        """Wait on `cond` (held by the caller) for at most `timeout` s of simulated time,
        freeing the world meanwhile; raises ClockStopped if the simulator is gone. Returns
        after a slice of wall time at most: the caller loops and reads the time again."""
        self.release()
        self.check()
        if timeout > 0:
            cond.wait(min(timeout, WAIT_SLICE))

    def sleep(self, seconds: float) -> None:
        """Let `seconds` of simulated time pass (the world freed)."""
        end = self.now() + seconds
        with self.changed:
            while self.now() < end:
                self.wait(self.changed, end - self.now())

    def describe(self) -> str:
        return (f"simulated time ({CLOCK_TOPIC}" + (", lockstep" if self.lockstep else "") + ")")

    def close(self) -> None:
        """Leave the lockstep: the simulator steps on without this process."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._held = False
        self._answer(self._t_ns or 0, "bye")
