"""Live changes during `rig cooperative`: keys on a terminal and commands over ROS 2."""

from __future__ import annotations

import sys

import numpy as np

from drivers.common import ros_exit
from rig.commands.exit_codes import InputError

#: Live increments: per key press, and the slew rates the controller ramps them in at
KEY_STEP_M, KEY_STEP_RAD, KEY_STEP_N = 0.002, 0.05, 0.5      # m, rad, N
SLEW_M, SLEW_RAD, SLEW_N = 0.01, 0.1, 2.0                    # m/s, rad/s, N/s


class LiveCommands:
    """Increments from the keyboard and from ROS 2 topics (thesis 6.3 teleop).

    /psm/cmd_vel (geometry_msgs/Twist): linear = Cartesian increment of the object in the
    world frame (m), angular = increment of its x-y-z Euler angles (rad); /psm/cmd_force
    (std_msgs/Float64): tension increment (N). Messages arrive on the executor's thread and
    are queued; the control loop applies them between two control cycles (`poll`), so a
    cycle never sees half an increment. Every message received is recorded on its topic.
    An increment with a NaN or one that would take a target out of the limits (workspace
    box, joint limits, reach) or the set-point out of [0, maximum_force] N or to the tension
    ceiling is refused: nothing moves, it is counted and reported, and the run goes on
    holding (docs/safety.md, "Bad input").
    """

    STEP_M = KEY_STEP_M
    STEP_RAD = KEY_STEP_RAD
    STEP_N = KEY_STEP_N
    TOPICS = ("/psm/cmd_vel", "/psm/cmd_force")

    def __init__(self, controller, ros: bool, keyboard: bool, recorder, names, limits, *,
                 maximum_force: float, say=None):
        from collections import deque

        self.c = controller
        self.rec = recorder
        self.names = list(names)
        self.limits = limits
        self.maximum_force = maximum_force
        self.say = say or (lambda text: None)
        self.keyboard = None
        self.node = None
        self.pending: deque = deque()
        self.received = {"/psm/cmd_vel": 0, "/psm/cmd_force": 0, "keyboard": 0}
        self.applied = {"/psm/cmd_vel": 0, "/psm/cmd_force": 0, "keyboard": 0}
        self.rejected: list[dict] = []
        self.last_applied: float | None = None
        self._t = 0.0
        if keyboard:
            self.keyboard = _Keyboard()
        if ros:
            self._start_ros()

    def __enter__(self) -> "LiveCommands":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def _start_ros(self) -> None:
        import threading

        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float64

        ros_exit.before_init()
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("rig_cooperative_teleop", context=self.context)
        ros_exit.after_node()
        # deque.append is atomic: the executor's thread only ever appends
        self.node.create_subscription(Twist, "/psm/cmd_vel", lambda m: self.pending.append(("/psm/cmd_vel", m)), 10)
        self.node.create_subscription(Float64, "/psm/cmd_force",
                                      lambda m: self.pending.append(("/psm/cmd_force", m)), 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, name="cooperative-ros-commands", daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:  # the context was shut down by close()
            pass

    def poll(self, t: float) -> None:
        """Apply what arrived since the last cycle; `t` is the rig clock (s)."""
        self._t = t
        while self.pending:
            topic, m = self.pending.popleft()
            self.received[topic] += 1
            if topic == "/psm/cmd_vel":
                linear = [m.linear.x, m.linear.y, m.linear.z]
                angular = [m.angular.x, m.angular.y, m.angular.z]
                self.rec.twist(topic, t, linear, angular)
                self._apply(topic, np.array(linear), np.array(angular), 0.0)
            else:
                self.rec.scalar(topic, t, m.data)
                self._apply(topic, np.zeros(3), np.zeros(3), float(m.data))
        if self.keyboard is not None:
            for key in self.keyboard.keys():
                self.apply_key(key)

    def _apply(self, source: str, d_translation: np.ndarray, d_rotation: np.ndarray, d_force: float) -> bool:
        c = self.c
        problem = None
        if not (np.all(np.isfinite(d_translation)) and np.all(np.isfinite(d_rotation)) and np.isfinite(d_force)):
            problem = "not a finite number"
        elif d_force:
            goal = c.force + c.force_offset + d_force
            if not 0.0 <= goal <= self.maximum_force or goal >= self.limits.tension_ceiling:
                problem = (f"tension set-point {goal:.2f} N outside [0, {self.maximum_force:g}] N "
                           f"or not below the ceiling {self.limits.tension_ceiling:g} N")
        if problem is None and (d_translation.any() or d_rotation.any()):
            saved = c.offset_translation.copy(), c.offset_rotation.copy()
            c.offset_translation = c.offset_translation + d_translation
            c.offset_rotation = c.offset_rotation + d_rotation
            problem = self._targets_violation()
            if problem is not None:
                c.offset_translation, c.offset_rotation = saved
        if problem is not None:
            self.rejected.append({"source": source, "t": self._t, "reason": problem})
            self.say(f"live command from {source} refused: {problem}\n")
            return False
        c.force_offset += d_force
        self.applied[source] += 1
        self.last_applied = self._t
        return True

    def _targets_violation(self) -> str | None:
        """First limit a target of the rest of the plan breaks with the current offsets."""
        from rig.model import psm_kinematics as K

        c = self.c
        end = c.t0 + c.motion.start + c.motion.duration
        for t in np.unique(np.linspace(max(self._t, c.t0), max(end, self._t), 11)):
            xd, _, _ = c.desired(t, targets=True)
            for n in self.names:
                try:
                    q = K.ik_rcm(c.to_rcm(n, xd[n]))
                except K.IKError as exc:
                    return f"{n} cannot reach its target: {exc}"
                problem = self.limits.plan_violation(n, q[None], np.zeros((1, 3)), xd[n][None])
                if problem:
                    return problem
        return None

    def apply_key(self, key: str) -> None:
        moves = {"d": (0, 1), "a": (0, -1), "w": (1, 1), "s": (1, -1), "r": (2, 1), "f": (2, -1)}
        turns = {"l": (2, 1), "j": (2, -1), "i": (1, 1), "k": (1, -1), "o": (0, 1), "u": (0, -1)}
        d_x, d_r, d_f = np.zeros(3), np.zeros(3), 0.0
        if key in moves:
            axis, sign = moves[key]
            d_x[axis] = sign * self.STEP_M
        elif key in turns:
            axis, sign = turns[key]
            d_r[axis] = sign * self.STEP_RAD
        elif key in "+=":
            d_f = self.STEP_N
        elif key in "-_":
            d_f = -self.STEP_N
        else:
            return
        self.received["keyboard"] += 1
        self._apply("keyboard", d_x, d_r, d_f)

    def summary(self, t_start: float) -> dict:
        """For the result document: counts per source, refusals, the offsets in force at the end."""
        return {"received": dict(self.received), "applied": dict(self.applied),
                "rejected": [{**r, "t": r["t"] - t_start} for r in self.rejected],
                "offset_translation": self.c.offset_translation.tolist(),
                "offset_rotation": self.c.offset_rotation.tolist(),
                "force_offset": float(self.c.force_offset),
                "last_applied": None if self.last_applied is None else self.last_applied - t_start}

    def show(self, t: float, tension: float, tips: dict) -> None:
        if self.keyboard is not None:
            pos = "  ".join(f"{n} {1000 * x[0]:7.1f} {1000 * x[1]:7.1f} {1000 * x[2]:7.1f} mm" for n, x in tips.items())
            sys.stderr.write(f"\r t {t:6.2f} s  tension {tension:6.2f} N (set {self.c.force_setpoint:5.2f})  {pos}"
                             "   [wasdrf move, ijkluo rotate, +/- force]")
            sys.stderr.flush()

    def close(self) -> None:
        if self.keyboard is not None:
            self.keyboard.close()
            self.keyboard = None
            sys.stderr.write("\n")
        if self.node is not None:

            self.executor.shutdown(timeout_sec=1.0)
            self.thread.join(timeout=2.0)
            ros_exit.teardown(self.node, self.context)
            self.node = None


class _Keyboard:
    """Non-blocking single keys from a terminal (cbreak mode, restored on close)."""

    def __init__(self):
        import termios
        import tty

        if not sys.stdin.isatty():
            raise InputError("--interactive needs a terminal on stdin")
        self.fd = sys.stdin.fileno()
        self.saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd)

    def keys(self) -> list[str]:
        import select

        out = []
        while select.select([sys.stdin], [], [], 0)[0]:
            ch = sys.stdin.read(1)
            if not ch:
                break
            out.append(ch)
        return out

    def close(self) -> None:
        import termios

        termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)
