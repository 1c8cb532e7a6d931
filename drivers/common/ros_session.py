"""One rclpy context, its nodes and executor threads for a procedure's ROS 2 devices.

Two nodes in one context (one DDS participant): `node` carries the streams (the arms'
joints at up to 500 Hz each, the mocap bodies), `control` the rare messages a run must see
at once: the simulated operator's replies, the arms' operating_state and error events,
their operating_state service and state commands. Each has its own executor thread. An
executor takes events in the order they came; when a starved process (two CPU burners,
three arms at 500 Hz and 16 mocap bodies) handles its streams slower than they arrive,
its queue grows, and an operator's reply queued behind it came more than 15 s late while
`rig sim` answered another client in 2-12 ms. On the control node it waits for nothing.

The streams' executor thread also keeps `executor_time()`: the monotonic time at
which the executor last came back from waiting for work. Drivers judge staleness on that
time instead of `time.monotonic()`:

    age = executor_time() - time of the last message

so a stream only counts as stale when the executor has been polling and found nothing for
longer than the timeout. If the process itself is starved (a fit or a plot holding the
GIL, other programs holding the CPUs) the executor cannot poll, `executor_time()` stands
still, and a healthy stream never looks stale. When the publisher really stops (the dVRK
or `rig sim` killed), the executor keeps waking every `POLL` s and the age grows at once:
detection takes the timeout plus at most `POLL` plus the watchdog's own period.
"""

from __future__ import annotations

import os
import threading
import time

from drivers.common import ros_exit

#: s, longest wait of the executor before it notes the time again (no message arrived)
POLL = 0.005
#: s, longest wait of the control executor (it only needs to see the session stop)
CONTROL_POLL = 0.05
#: s, longest wait for the executor thread to return when the session stops (a starved
#: process: the thread must get the CPU once to see the request)
STOP_WAIT = 10.0


def domain_text() -> str:
    """The ROS 2 domain and discovery range this process uses, for messages."""
    domain = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
    scope = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    return f"ROS_DOMAIN_ID={domain}" + (f", discovery {scope}" if scope else "")


def make_executor(kind: str, context):
    """The rclpy executor of a process: "events" (rclpy's EventsExecutor: its queue is
    C++, and with two arms at 500 Hz it took 0.12 of a core where the SingleThreadedExecutor
    took 0.34, and `rig sim` dropped from 0.69 to 0.32) or "single". Spin it with
    spin_once(timeout) in a loop: the events executor's spin() held `rig sim`'s other threads
    off (no stream, no exit on SIGTERM)."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    if kind == "single":
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor(context=context)
    raise ValueError(f"executor must be 'events' or 'single', got {kind!r}")


class RosSession:
    """rclpy context + node + executor thread (see the module docstring).

    name: the node's name; executor: "events" or "single" (`make_executor`). Use `node`
    to create drivers, then `start()`; `close()` stops the threads and parks the participant.
    """

    def __init__(self, name: str = "rig", executor: str = "events"):
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        ros_exit.before_init()
        self.context = Context()
        # The run engine owns SIGINT/SIGTERM: rclpy's handlers would shut the context
        # under a procedure instead of letting it hold the arms and close its recording.
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = rclpy.create_node(name, context=self.context)
            ros_exit.after_node()
            #: the node of the rare messages that must not queue behind the streams
            self.control = rclpy.create_node(f"{name}_control", context=self.context)
            self.executor = self.control_executor = None
            self.executor_kind = executor
        except BaseException:
            rclpy.shutdown(context=self.context)
            raise
        self._t = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"ros-{name}", daemon=True)
        self._control_thread = threading.Thread(target=self._spin_control, name=f"ros-{name}-control", daemon=True)
        self.spins = 0
        self.stopped = False
        from drivers.common.time_base import WallTime

        #: the clock the session's drivers wait on (`drivers.common.time_base`): the wall clock, or
        #: the simulator's /clock (set before `start()`, `rig.devices.factory`)
        self.time = WallTime()

    def executor_time(self) -> float:
        """Monotonic s at which the executor last finished a wait (see the module docstring)."""
        return self._t

    def start(self) -> None:
        # made once the drivers' subscriptions exist (the events executor registers what
        # the node has when the node is added)
        self.executor = make_executor(self.executor_kind, self.context)
        self.executor.add_node(self.node)
        # a SingleThreadedExecutor: its node's traffic is rare, and it takes endpoints made
        # after it started (a person's side channel subscribes on demand); the events
        # executor registers only what the node has when the node is added
        self.control_executor = make_executor("single", self.context)
        self.control_executor.add_node(self.control)
        self._t = time.monotonic()
        self._thread.start()
        self._control_thread.start()

    def _spin(self) -> None:
        self._spin_loop(self.executor, POLL, streams=True)

    def _spin_control(self) -> None:
        self._spin_loop(self.control_executor, CONTROL_POLL, streams=False)

    def _spin_loop(self, executor, poll: float, streams: bool) -> None:
        """Spin `executor` until the session stops; the streams' loop notes executor_time."""
        while not self._stop.is_set():
            try:
                executor.spin_once(timeout_sec=poll)
            except Exception:  # noqa: BLE001 - the context is shut down by close()
                if self._stop.is_set() or not self.context.ok():
                    return
                raise
            if streams:
                self._t = time.monotonic()
                self.spins += 1
                self.time.poll()

    def stop(self) -> bool:
        """Stop spinning: the executor thread has returned and the executor is shut down,
        so the drivers may destroy their endpoints (destroyed under a spinning executor,
        an endpoint takes the process down with a segmentation fault: rclpy#663, and
        the EventsExecutor's rclpy#1644). Idempotent. False if the thread did not return
        within STOP_WAIT s: then nothing may be destroyed (`stopped` stays False)."""
        self._stop.set()
        deadline = time.monotonic() + STOP_WAIT
        for thread in (self._thread, self._control_thread):
            if thread.is_alive():
                thread.join(timeout=max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive() or self._control_thread.is_alive():
            return False
        if not self.stopped:
            for executor in (self.executor, self.control_executor):
                if executor is not None:
                    executor.shutdown(timeout_sec=STOP_WAIT)
        self.stopped = True
        return True

    def close(self) -> None:
        """Stop spinning, then park the nodes and the context until the process ends: a
        participant deleted after a peer was killed mid-write crashed the process
        (`drivers.common.ros_exit`). A thread that would not stop leaves them to the process's end too."""
        if not self.stop():
            return
        ros_exit.teardown((self.control, self.node), self.context)
