"""The operator as a device: the steps of a procedure that need a person's hands.

Mount the marker bodies, take the object off the tool tips or put it on, hang a known
mass from the load cell, guide the tool tips onto a common point. Procedures ask an
`Operator` (drivers.interfaces) and go on when it answers. Three operators:

* `ConsoleOperator`: a person at this terminal. The request is printed on stderr and the
  person presses Enter when done (so a script answers by writing a newline to stdin); with
  `yes=True` (`--yes`) it is taken as done at once, for a rig prepared beforehand.
* `RosOperator`: `rig sim`'s simulated operator, over a side channel of ROS 2 topics, so
  that a procedure in another process runs unattended against the simulated rig.
* `drivers.operator.sim.SimOperator`: the in-process simulated rig does it itself.

The side channel (served by `drivers.operator.fake_operator_server.FakeOperatorServer` in `rig sim`):

  /rig_sim/operator/request  std_msgs/String  {"id": "...", "action": ACTION, ...}
  /rig_sim/operator/reply    std_msgs/String  {"id": "...", "ok": true|false, "detail": "..."}

ACTION is one of ACTIONS, with its fields: confirm {message}; detach_object {};
attach_object {kind (optional): "spring" or "string"}; hang_mass {kg, element (optional:
which object element's cell)}; touch {arms: [names], index, goal: [x, y, z] m in the
world}; unplug {device: "loadcell"} (a person pulling a cable: fault injection); fault
{arm, kind: "joint_limit" (with joint: 1-3), "power_loss" or "servo_watchdog" (with timeout:
s, 0: off)}
(an arm fault injected for tests, drivers.operator.sim.SimOperator.fault). Both topics are
reliable with depth 10; the client matches a reply by its id and ignores the others
(several clients may share the channel).
"""

from __future__ import annotations

import itertools
import json
import os
import threading
import time

import click
import numpy as np

from rig.faults import DeviceFault

REQUEST_TOPIC = "/rig_sim/operator/request"
REPLY_TOPIC = "/rig_sim/operator/reply"
ACTIONS = ("confirm", "detach_object", "attach_object", "hang_mass", "touch", "unplug", "fault")


class OperatorError(DeviceFault):
    """The operator did not do what was asked (no answer, or an answer saying why not)."""


def check_mass(kg) -> None:
    """A mass a person can hang: finite and >= 0 kg (as the simulated operator checks it)."""
    if not (np.isfinite(kg) and kg >= 0):
        raise OperatorError(f"a mass must be >= 0 kg, got {kg}")


class ConsoleOperator:
    """A person at this terminal (see the module docstring); `yes`: take every request as done."""

    def __init__(self, yes: bool = False):
        self.yes = yes

    def _ask(self, text: str) -> None:
        if self.yes:
            click.echo(f"{text}: taken as done (--yes)", err=True)
            return
        try:
            click.prompt(f"{text}; press Enter when done", default="", show_default=False, err=True)
        except click.Abort:  # end of input: nobody is there to answer
            raise OperatorError(f"no answer on stdin to: {text} (give --yes, or answer with Enter)") from None

    def confirm(self, message: str) -> None:
        self._ask(message)

    def detach_object(self) -> None:
        self._ask("Take the object (spring or suture) and the load cell off the tool tips")

    def attach_object(self, kind: str | None = None) -> None:
        self._ask(f"Attach the {kind or 'object'} and the load cell between the tool tips")

    def hang_mass(self, kg: float, element: int | None = None) -> None:
        check_mass(kg)
        cell = "the load cell" if element is None else f"the load cell of object element {element}"
        self._ask(f"Take everything off {cell}" if kg == 0 else f"Hang {kg:.3f} kg from {cell} and let it settle")

    def touch(self, arms: dict, point_index: int, goal_world: np.ndarray) -> None:
        self._ask(f"Touch point {point_index + 1}: bring the tool tips of {' and '.join(arms)} together on one "
                  "point of the fixture (hand-guide or jog them) and hold still")


#: s, how often a waiting request calls `RosOperator.watch`
WATCH_EVERY = 0.1


class RosOperator:
    """`rig sim`'s simulated operator over the side channel (see the module docstring).

    node: an rclpy node someone else spins; timeout: s to wait for each answer.
    """

    _ids = itertools.count(1)

    def __init__(self, node, timeout: float = 30.0, time_base=None):
        from rclpy.qos import QoSProfile
        from std_msgs.msg import String

        from drivers.common.time_base import WallTime

        self.node = node
        self.timeout = float(timeout)
        #: the clock of `timeout` (`drivers.common.time_base`): simulated time when the rig follows one,
        #: so a person's steps take what they take in the world, however busy the machine
        self.time = time_base if time_base is not None else WallTime()
        #: called every WATCH_EVERY s while a request waits for its reply; it raises the
        #: rig's device fault (an arm's stale stream or FAULT) to end the wait at once.
        #: None: the wait ends only on the reply or the timeout.
        self.watch = None
        self._String = String
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._replies: dict[str, dict] = {}
        qos = QoSProfile(depth=10)
        self._pub = node.create_publisher(String, REQUEST_TOPIC, qos)
        self._sub = node.create_subscription(String, REPLY_TOPIC, self._on_reply, qos)

    def _on_reply(self, msg) -> None:
        try:
            doc = json.loads(msg.data)
            key = str(doc["id"])
        except (ValueError, KeyError, TypeError):
            return  # not a reply of this protocol
        with self._cond:
            self._replies[key] = doc
            self._cond.notify_all()

    def wait_for_server(self, timeout: float) -> bool:
        """True once `rig sim`'s operator listens on the request topic."""
        deadline = time.monotonic() + timeout
        while self._pub.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def request(self, action: str, **fields) -> str:
        """Send one request and wait for its reply; returns the reply's detail."""
        if action not in ACTIONS:
            raise ValueError(f"unknown operator action {action!r}; known: {', '.join(ACTIONS)}")
        if not self.wait_for_server(self.timeout):
            raise OperatorError(f"{REQUEST_TOPIC}: nobody serves the simulated operator; start `rig sim`, or set "
                                "[operator] driver = 'console' in rig.toml")
        key = f"{os.getpid()}-{next(self._ids)}"
        self._pub.publish(self._String(data=json.dumps({"id": key, "action": action, **fields})))
        tb = self.time
        deadline = tb.now() + self.timeout
        while True:
            with self._cond:
                left = deadline - tb.now()
                if key not in self._replies and left > 0:
                    tb.wait(self._cond, min(left, WATCH_EVERY) if self.watch is not None else left)
                if key in self._replies:
                    doc = self._replies.pop(key)
                    break
                if deadline - tb.now() <= 0:
                    raise OperatorError(f"the simulated operator did not answer {action!r} within "
                                        f"{self.timeout:g} s on {REPLY_TOPIC}; is `rig sim` still running?")
            if self.watch is not None:
                self.watch()  # a device fault meanwhile (rig sim killed: the arms' streams stop) ends it
        if not doc.get("ok"):
            raise OperatorError(f"the simulated operator could not {action.replace('_', ' ')}: "
                                f"{doc.get('detail', 'no reason given')}")
        return str(doc.get("detail", ""))

    def confirm(self, message: str) -> None:
        self.request("confirm", message=message)

    def detach_object(self) -> None:
        self.request("detach_object")

    def attach_object(self, kind: str | None = None) -> None:
        self.request("attach_object", **({"kind": kind} if kind else {}))

    def hang_mass(self, kg: float, element: int | None = None) -> None:
        check_mass(kg)
        self.request("hang_mass", kg=float(kg), **({} if element is None else {"element": int(element)}))

    def unplug(self, device: str) -> None:
        self.request("unplug", device=device)

    def fault(self, arm: str, kind: str, joint: int = 1, timeout: float = 0.1) -> None:
        """Inject an arm fault in `rig sim` (tests): kind "joint_limit", "power_loss" or
        "servo_watchdog" (drivers.operator.sim.SimOperator.fault says what each does)."""
        self.request("fault", arm=arm, kind=kind, joint=int(joint), timeout=float(timeout))

    def touch(self, arms: dict, point_index: int, goal_world: np.ndarray) -> None:
        self.request("touch", arms=list(arms), index=int(point_index),
                     goal=[float(x) for x in np.asarray(goal_world, float)])

    def close(self) -> None:
        self.node.destroy_publisher(self._pub)
        self.node.destroy_subscription(self._sub)
