"""How a procedure's loop advances: one tick per rig period, on simulated or wall time.

A procedure never sleeps or steps a world itself; it calls `clock.tick()` once per period
and reads `clock.now()`. On the simulated rig the tick *is* the physics step, so a
procedure runs faster than real time and stays deterministic; on the real rig the tick
waits for the next period of the wall clock. Fakes that emit samples on their own rate
(mocap at 120 Hz, the arm's trajectory generator) register a listener and run on the
same time line as the arms.

Times are seconds; rates are Hz.
"""

from __future__ import annotations

import time
from typing import Callable, Protocol, runtime_checkable

Listener = Callable[[float], None]


@runtime_checkable
class Clock(Protocol):
    """The rig's time line."""

    rate: float  # Hz, one tick per period

    def now(self) -> float:
        """Seconds on this clock."""
        ...

    def tick(self) -> None:
        """Return when the next period starts (after the listeners have run)."""
        ...

    def add_listener(self, fn: Listener) -> None:
        """Call `fn(now)` after every tick (fakes emit their samples from here)."""
        ...


class _Listeners:
    def __init__(self) -> None:
        self._listeners: list[Listener] = []

    def add_listener(self, fn: Listener) -> None:
        self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        """Stop calling `fn` (no error if it was not registered)."""
        try:
            self._listeners.remove(fn)
        except ValueError:
            pass

    def _notify(self, t: float) -> None:
        # Iterate over a copy: a listener may remove itself (a finished trajectory).
        for fn in tuple(self._listeners):
            fn(t)


class SimClock(_Listeners):
    """The simulated rig's clock: a tick is one `world.step()` of `world.dt` seconds.

    `now()` is the world's time (s since the world was made). If the world was built with
    `pace=True` each step waits for the wall clock, so the same loop runs in real time.
    """

    def __init__(self, world) -> None:
        super().__init__()
        self.world = world
        self.rate = 1.0 / world.dt
        self.period = world.dt

    def now(self) -> float:
        return self.world.t

    def tick(self) -> None:
        self.world.step()
        self._notify(self.world.t)

    def sleep(self, duration: float) -> None:
        """Tick for `duration` seconds of clock time (rounded to whole periods)."""
        for _ in range(int(round(duration * self.rate))):
            self.tick()


class WallClock(_Listeners):
    """Real time at a fixed rate (Hz): `tick()` sleeps until the next period boundary.

    Boundaries are `start + k / rate`, computed from the tick count rather than by adding
    periods to the last wake-up, so sleep jitter never accumulates into drift. A tick that
    is called after its boundary has passed is an overrun: it returns at once and is
    counted in `overruns`; if the loop fell more than one whole period behind, the missed
    boundaries are skipped (counted in `skipped`) instead of being replayed in a burst.

    `now()` is seconds since the Unix epoch, advanced by `time.perf_counter()` so it is
    monotonic and fine-grained, and comparable with ROS 2 header stamps (system time).
    """

    def __init__(self, rate: float) -> None:
        super().__init__()
        if not rate > 0:
            raise ValueError(f"clock rate must be > 0 Hz, got {rate}")
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        self._perf0 = time.perf_counter()
        self._epoch0 = time.time()
        self._k = 0
        self.overruns = 0
        self.skipped = 0

    def now(self) -> float:
        return self._epoch0 + (time.perf_counter() - self._perf0)

    def tick(self) -> None:
        self._k += 1
        deadline = self._perf0 + self._k * self.period
        lag = time.perf_counter() - deadline
        if lag > 0:
            self.overruns += 1
            behind = int(lag // self.period)
            if behind:
                self._k += behind
                self.skipped += behind
        else:
            # sleep() alone may overshoot by the timer slack (~50 us); good enough at 1 kHz.
            time.sleep(-lag)
        self._notify(self.now())

    def sleep(self, duration: float) -> None:
        """Tick for `duration` seconds (rounded to whole periods)."""
        for _ in range(int(round(duration * self.rate))):
            self.tick()


class StreamClock(WallClock):
    """Real time paced by the devices' own streams: `tick()` returns when every source has
    delivered a new sample since the last tick (and at least `min_fraction` of a period has
    passed), or at the latest `max_fraction` periods after the last tick.

    Over the wire a loop on its own timer beats against the arms' stream: some ticks find
    no new measured_js and act on data several ms old, the next find two; a stiff control
    loop (the cooperative impedance) can go unstable on that jitter. Paced by the stream,
    every control step acts on a sample that is fresh, as the dVRK's own controllers do.

    sources: objects with `received` (a count of samples) and `wait_newer(count, timeout)`
    (block until `received > count`; True if so). Late ticks (a source silent until the
    deadline) are counted in `overruns`; `now()` is seconds since the epoch, as WallClock.
    """

    def __init__(self, rate: float, sources, min_fraction: float = 0.5, max_fraction: float = 1.5) -> None:
        super().__init__(rate)
        self.sources = list(sources)
        self.min_fraction = float(min_fraction)
        self.max_fraction = float(max_fraction)
        self._last = time.perf_counter()
        self._seen = [s.received for s in self.sources]

    def add_source(self, source) -> None:
        self.sources.append(source)
        self._seen.append(source.received)

    def set_rate(self, rate: float, min_fraction: float | None = None) -> None:
        """Pace at `rate` Hz from now on (a procedure whose loop runs slower than [rig]
        rate); `min_fraction`: of a period between two ticks at least (1.0 for a loop
        slower than its sources, which would otherwise tick at every new sample)."""
        if not rate > 0:
            raise ValueError(f"clock rate must be > 0 Hz, got {rate}")
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        if min_fraction is not None:
            self.min_fraction = float(min_fraction)

    def tick(self) -> None:
        self._k += 1
        earliest = self._last + self.min_fraction * self.period
        deadline = self._last + self.max_fraction * self.period
        late = False
        for i, s in enumerate(self.sources):
            left = deadline - time.perf_counter()
            if not s.wait_newer(self._seen[i], max(0.0, left)):
                late = True
        rest = earliest - time.perf_counter()
        if rest > 0:
            time.sleep(rest)
        now = time.perf_counter()
        if late:
            self.overruns += 1
            behind = int((now - self._last) // self.period) - 1
            if behind > 0:
                self.skipped += behind
        self._last = now
        self._seen = [s.received for s in self.sources]
        self._notify(self.now())
