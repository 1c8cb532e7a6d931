"""The operator's side channel, emulated: the far end of `drivers.operator.driver.RosOperator`.

`FakeOperatorServer` is what `rig sim` serves on the request / reply topics of
`drivers.operator.driver`: each request is done by a `drivers.operator.sim.SimOperator` on the
served world, so a procedure in another process gets its manual steps done unattended.
Requests arrive on the executor thread and are queued; `rig sim`'s main thread, the only
one that touches the world, calls `apply()` between steps and publishes the replies.
"""

from __future__ import annotations

import json
from collections import deque

from drivers.operator.driver import ACTIONS, REPLY_TOPIC, REQUEST_TOPIC, OperatorError
from drivers.operator.sim import SimOperator


class FakeOperatorServer:
    """`SimOperator` on the ROS 2 side channel (see the module docstring); node: rig sim's node."""

    def __init__(self, operator: SimOperator, node):
        from rclpy.qos import QoSProfile
        from std_msgs.msg import String

        self.operator = operator
        self.node = node
        self._String = String
        self._queue: deque = deque()
        qos = QoSProfile(depth=10)
        self._pub = node.create_publisher(String, REPLY_TOPIC, qos)
        self._sub = node.create_subscription(String, REQUEST_TOPIC, lambda m: self._queue.append(m), qos)
        self.served: dict[str, int] = {}
        self.gone = False  # the person left (unplug "operator"): requests go unanswered
        operator.cables["operator"] = self._leave

    def _leave(self) -> None:
        self.gone = True

    def apply(self) -> None:
        """Carry out the queued requests and reply to each (main thread, between steps);
        once the person has left, requests are dropped unanswered."""
        while self._queue:
            msg = self._queue.popleft()
            if self.gone:
                continue
            try:
                doc = json.loads(msg.data)
                key = doc["id"]
                action = doc["action"]
            except (ValueError, KeyError, TypeError):
                self.node.get_logger().warning(f"operator: malformed request ignored: {msg.data[:200]!r}")
                continue
            ok, detail = True, "done"
            self.operator.release()  # the person lets go of the tips for whatever comes next
            try:
                self._do(action, doc)
            except (OperatorError, ValueError, TypeError, KeyError) as exc:
                ok, detail = False, str(exc)
            self.served[action] = self.served.get(action, 0) + 1
            self._pub.publish(self._String(data=json.dumps({"id": key, "ok": ok, "detail": detail})))

    def _do(self, action: str, doc: dict) -> None:
        op = self.operator
        if action not in ACTIONS:
            raise OperatorError(f"unknown action {action!r}; known: {', '.join(ACTIONS)}")
        if action == "confirm":
            op.confirm(str(doc.get("message", "")))
        elif action == "detach_object":
            op.detach_object()
        elif action == "attach_object":
            op.attach_object(doc.get("kind"))
        elif action == "hang_mass":
            op.hang_mass(float(doc["kg"]), doc.get("element"))
        elif action == "unplug":
            op.unplug(str(doc.get("device", "")))
        elif action == "fault":
            op.fault(str(doc.get("arm", "")), str(doc.get("kind", "")), int(doc.get("joint", 1)),
                     float(doc.get("timeout", 0.1)))
        else:
            op.touch(list(doc["arms"]), int(doc.get("index", 0)), doc["goal"])
