"""rig sim on simulated time repeats its newest /clock while its world's loop is held up
anywhere (rig.sim_server.ros_node.SimServer._repeat_while_held): its followers then know it
lives, and its time does not move. Held up in the kernel, on a loaded machine (a read of a
served load cell's pty), it published nothing for 1-3.6 s, and a procedure stopped on
ClockStopped with the simulator alive."""

import threading
import time

from drivers.common.time_base import HEARTBEAT
from rig.sim_server.ros_node import SimServer


class _Held:
    """What the repeater reads of a SimServer whose loop published a clock and then hung."""

    def __init__(self):
        self.stop = threading.Event()
        self._clock_at = time.monotonic()
        self.last_clock = self._clock_at
        self.repeats: list[float] = []

    def _repeat_clock(self) -> None:
        self.repeats.append(time.monotonic())
        self._clock_at = time.monotonic()


def test_a_world_loop_held_up_gets_its_clock_repeated_a_heartbeat_after_the_last():
    held = _Held()
    thread = threading.Thread(target=SimServer._repeat_while_held, args=(held,), daemon=True)
    thread.start()
    try:
        guard = time.monotonic() + 60.0  # against a hang only
        while len(held.repeats) < 3:
            assert time.monotonic() < guard, held.repeats
            time.sleep(0.01)
    finally:
        held.stop.set()
        thread.join(timeout=10.0)
    # never sooner than a heartbeat after the clock before (a loop that publishes is not repeated)
    times = [held.last_clock, *held.repeats]
    assert all(b - a > HEARTBEAT for a, b in zip(times, times[1:])), times
    assert not thread.is_alive()

