"""The simulator's side of lockstep: who follows its clock, and the wait for their answers.

`rig sim --sim-time` publishes its world's time on /clock once per ROS period. A process
that follows it (`drivers.common.time_base.SimTime`) answers each period on
`drivers.common.time_base.ANSWER_TOPIC`; `Lockstep.wait(t)` returns once every such process has
answered the period at `t` (a process in hold mode: that period, unless the next one its
loop acts on is later; in free mode: within `free_lead` s of it, so its executor may
pipeline) and the commands its answers
count have all been received. A process that says `bye` leaves; one silent for `timeout` s
of wall time while the world waits on it is let go (logged, counted in `lost`) and
rejoins with its next answer: a killed procedure never freezes the world for good. A
process that holds the world while it computes (or waits, free, for its load cell's
reader) repeats its last answer every `drivers.common.time_base.HEARTBEAT` s from its executor
thread, so only a dead or starved one goes silent that long. While it waits, the
simulator repeats its newest /clock as often (`repeat`), so that a process that has
answered tells a simulator waiting for another from one that died.

Commands cannot be told apart by sender (a ROS message carries none), so the check is on
totals: the commands received since the clients joined against the sum of what their
answers say they sent. A client that is not in lockstep (the dVRK's own Python client
beside a procedure) only adds to the received total, which can let a lockstep client's
command still in flight be missed for a period; `late_commands` counts the commands
still missing after `command_wait` s of wall time (a command published before its
subscription matched is lost: the wait then takes it as come, once).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from drivers.common.time_base import HEARTBEAT

#: s of wall time a follower may leave the world waiting without a word (no answer, no
#: repeat of one) before it is let go. Every live follower speaks every HEARTBEAT s, so
#: this is how long a process may be held off the CPU: on a 2-core machine with two CPU
#: burners and four other sessions' tests (load average 13), 1 s let go of followers that
#: were alive (rig sim's log: 4 in 3 triangle runs)
TIMEOUT = 3.0


@dataclass
class Client:
    """One process in lockstep: the newest period it answered (ns), the commands it says it
    sent, its mode (hold or free) and the wall time of its last answer."""

    answered_ns: int
    sent: int
    mode: str
    heard: float
    next_ns: int = 0


def parse_answer(frame_id: str) -> tuple[str, int, str, int]:
    """(client, sent, mode, next) of an answer's frame_id ("client=<id> sent=<n> mode=<m>
    next=<ns>", next optional); ValueError on anything else."""
    fields = dict(part.split("=", 1) for part in frame_id.split() if "=" in part)
    try:
        client, sent, mode = fields["client"], int(fields["sent"]), fields["mode"]
        next_ns = int(fields.get("next", 0))
    except (KeyError, ValueError):
        raise ValueError(f"not a lockstep answer: {frame_id!r}") from None
    if mode not in ("hold", "free", "bye"):
        raise ValueError(f"not a lockstep mode: {mode!r}")
    return client, sent, mode, next_ns


class Lockstep:
    """The lockstep clients of a simulator (see the module docstring).

    node: the simulator's node (the answers' subscription); timeout: s of wall time a
    client may leave the world waiting before it is let go; free_lead: s of simulated time
    a client in free mode may lag; command_wait: s of wall time to wait for commands
    counted but not yet received; log(text): where joins, leaves and losses are told;
    repeat(): publishes the newest /clock again (every HEARTBEAT s of a wait).
    """

    def __init__(self, node, timeout: float = TIMEOUT, free_lead: float = 0.05, command_wait: float = 0.5, log=None,
                 repeat=None):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Header

        from drivers.common.time_base import ANSWER_TOPIC

        self.timeout = float(timeout)
        self.free_lead_ns = int(round(free_lead * 1e9))
        self.command_wait = float(command_wait)
        self._log = log or (lambda text: None)
        self._repeat = repeat or (lambda: None)
        self.clients: dict[str, Client] = {}
        self.cond = threading.Condition()
        self.received = 0  # commands received (every client's, and any other publisher's)
        self.settled = 0  # the commands counted by clients that left (their last answer's)
        self._departed: dict[str, int] = {}
        self.lost = 0
        self.late_commands = 0
        self.waits = 0
        self.wait_s = 0.0  # wall s the world spent waiting for answers
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self._sub = node.create_subscription(Header, ANSWER_TOPIC, self._on_answer, qos)

    @property
    def active(self) -> bool:
        """Some process follows the clock in lockstep."""
        return bool(self.clients)

    def command_received(self) -> None:
        """Count one command received (from the executor thread, as it arrives)."""
        with self.cond:
            self.received += 1
            self.cond.notify_all()

    def _on_answer(self, m) -> None:
        try:
            client, sent, mode, next_ns = parse_answer(m.frame_id)
        except ValueError:
            return
        ns = m.stamp.sec * 1_000_000_000 + m.stamp.nanosec
        with self.cond:
            known = self.clients.get(client)
            if mode == "bye":
                if known is not None:
                    self._depart(client)
                    self._log(f"lockstep: {client} left at t = {ns * 1e-9:.3f} s")
            elif known is None:
                # its count goes on from where it left, if it was let go
                self.settled -= self._departed.pop(client, 0)
                self.clients[client] = Client(ns, sent, mode, time.monotonic(), next_ns)
                self._log(f"lockstep: {client} follows the clock from t = {ns * 1e-9:.3f} s ({mode})")
            else:
                known.answered_ns = max(known.answered_ns, ns)
                known.sent = max(known.sent, sent)
                known.mode = mode
                known.next_ns = next_ns
                known.heard = time.monotonic()
            self.cond.notify_all()

    def _depart(self, client: str) -> None:
        c = self.clients.pop(client)
        self.settled += c.sent
        self._departed[client] = c.sent

    def _pending(self, t_ns: int) -> list[str]:
        # hold: the period itself, unless the loop acts next on a later one; free: within the lead
        return [name for name, c in self.clients.items()
                if ((c.answered_ns < t_ns and t_ns >= c.next_ns) if c.mode == "hold"
                    else c.answered_ns < t_ns - self.free_lead_ns)]

    def wait(self, t_ns: int, stop: threading.Event) -> None:
        """Block until every client answered the period at `t_ns` and the commands they
        counted arrived (see the class docstring), or `stop` is set."""
        began = repeated = time.monotonic()
        waited = False
        with self.cond:
            while not stop.is_set():
                if time.monotonic() - repeated > HEARTBEAT:
                    repeated = time.monotonic()
                    self._repeat()
                pending = self._pending(t_ns)
                if pending:
                    now = time.monotonic()
                    for name in pending:
                        c = self.clients[name]
                        if now - c.heard > self.timeout:
                            self._depart(name)
                            self.lost += 1
                            self._log(f"lockstep: {name} left the world waiting {self.timeout:g} s at t = "
                                      f"{t_ns * 1e-9:.3f} s; stepping on without it until it answers again")
                    if self._pending(t_ns):
                        waited = True
                        self.cond.wait(0.05)
                    continue
                owed = self.settled + sum(c.sent for c in self.clients.values())
                if self.received >= owed:
                    break
                if time.monotonic() - began > self.command_wait:
                    # counted but never received: sent before the subscription matched (lost,
                    # as DDS drops a volatile message nobody matched yet), or still on its
                    # way. Count them as come, so that the next periods do not wait again.
                    self.late_commands += owed - self.received
                    self.received = owed
                    break
                waited = True
                self.cond.wait(0.005)
        if waited:
            self.waits += 1
        self.wait_s += time.monotonic() - began
