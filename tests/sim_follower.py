"""This test process as a follower of `rig sim --sim-time`'s clock, in lockstep, as a procedure is.

A test that drives `rig sim` from its own process (RosArm, the operator channel) follows
the world's /clock as `rig.devices.factory` makes a procedure follow it
(docs/simulated-time.md): one RosSession whose drivers wait, time out and age on the
world's time (`drivers.common.time_base.SimTime`), free while the test waits, and held by
`stream()`, a loop of commands at a rate of the world's time (the world steps on once each
period's command is out). So what the test sees does not depend on how busy the machine
is: a stream at 100 Hz of the world's time stays one, however late this process runs.

    with ServedRig(folder, sim_time=True) as served, ros_environment(served.domain):
        follower = SimFollower("my_test")
        arm = follower.arm("/PSM1")
        follower.start()
        ...
        follower.close()

Waits that are the world's (`sleep`, `wait_for`) end on the world's time; a world that
stops raises ClockStopped after `drivers.common.time_base.STALL` s of wall time.
"""

from __future__ import annotations

from typing import Callable


class SimFollower:
    """A RosSession on the world's /clock in lockstep, its drivers and a loop (see the module docstring)."""

    def __init__(self, name: str):
        from drivers.common.ros_session import RosSession
        from drivers.common.time_base import SimTime

        self.session = RosSession(name)
        self.time = SimTime(self.session.node, lockstep=True, polled=self.session.executor_time)
        self.session.time = self.time
        self._drivers: list = []
        self._closed = False

    # -- drivers (made before start(): the streams' executor takes what the node has then) ----
    def arm(self, namespace: str, watchdog: float = 0.5):
        """A RosArm on `namespace` whose waits and stream age are on the world's time."""
        from drivers.arm.dvrk_arm import RosArm

        arm = RosArm(self.session.node, namespace, watchdog=watchdog, spin=False, polled=self.session.executor_time,
                     control_node=self.session.control, time_base=self.time)
        self._drivers.append(arm)
        return arm

    def operator(self, timeout: float = 20.0):
        """The simulated operator's channel; `timeout`: s of the world's time per answer."""
        from drivers.operator.driver import RosOperator

        operator = RosOperator(self.session.control, timeout=timeout, time_base=self.time)
        self._drivers.append(operator)
        return operator

    def start(self, timeout: float = 120.0) -> "SimFollower":
        """Spin, and wait (wall s: discovery) for the world's first /clock."""
        from drivers.common.ros_session import domain_text

        self.session.start()
        if not self.time.wait_heard(timeout):
            raise AssertionError(f"no /clock within {timeout:g} s on {domain_text()}: is `rig sim --sim-time` running?")
        return self

    # -- the world's time ---------------------------------------------------------------------
    def now(self) -> float:
        """s of the world's time."""
        return self.time.now()

    def sleep(self, seconds: float) -> None:
        """Let `seconds` of the world's time pass (the world free)."""
        self.time.sleep(seconds)

    def wait_for(self, done: Callable[[], bool], seconds: float, poll: float = 0.01) -> bool:
        """Whether `done()` holds within `seconds` of the world's time (looked at every `poll` s of it)."""
        deadline = self.now() + seconds
        while not done():
            if self.now() >= deadline:
                return bool(done())
            self.sleep(poll)
        return True

    def stream(self, rate: float, command: Callable[[], None], sources, seconds: float,
               until: Callable[[], bool] | None = None) -> int:
        """Call `command()` once a period of `rate` Hz of the world's time, for `seconds` of it
        or until `until()` holds (looked at after each command), the world held: it does not
        step past a period until that period's command is out and every arm of `sources`
        has sent its sample of the next. Returns the commands sent; the world is free again
        after."""
        from rig.devices.clock import SimTimeClock

        clock = SimTimeClock(rate, sources, self.time, min_fraction=1.0, polled=self.session.executor_time)
        sent = 0
        try:
            for _ in range(int(round(seconds * rate))):
                command()
                sent += 1
                if until is not None and until():
                    break
                clock.tick()
        finally:
            self.time.release()
        return sent

    def close(self) -> None:
        """Stop spinning, close the drivers, leave the lockstep, park the participant."""
        if self._closed:
            return
        self._closed = True
        stopped = self.session.stop()  # no endpoint is destroyed under a spinning executor
        if stopped:
            for driver in reversed(self._drivers):
                driver.close()
        self.time.close()
        self.session.close()
