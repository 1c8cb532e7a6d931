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
from array import array
from typing import Callable, Protocol, runtime_checkable

Listener = Callable[[float], None]


@runtime_checkable
class Clock(Protocol):
    """The rig's time line."""

    rate: float  # Hz, one tick per period
    overruns: int  # ticks that came late (0 on the simulated rig's clock: it is never late)
    skipped: int   # periods skipped to catch up (0 on the simulated rig's clock)

    def now(self) -> float:
        """Seconds on this clock."""
        ...

    def tick(self) -> None:
        """Return when the next period starts (after the listeners have run)."""
        ...

    def add_listener(self, fn: Listener) -> None:
        """Call `fn(now)` after every tick (fakes emit their samples from here)."""
        ...


@runtime_checkable
class PacedClock(Clock, Protocol):
    """A clock that waits on its sources (the ROS arms' streams, or the world's /clock): a
    loop slower than [rig] rate can pace it (StreamClock, SimTimeClock)."""

    def set_rate(self, rate: float, min_fraction: float | None = None) -> None: ...


class _Listeners:
    """Listeners, and the loop's timing: how long the procedure computed between two ticks."""

    def __init__(self) -> None:
        self._listeners: list[Listener] = []
        self._work = array("d")  # s of wall time from the return of one tick to the call of the next
        self._returned: float | None = None

    def _tick_called(self) -> None:
        if self._returned is not None:
            self._work.append(time.perf_counter() - self._returned)

    def _tick_returns(self) -> None:
        self._returned = time.perf_counter()

    def loop_timing(self) -> dict:
        """The loop's tick time against its period: the wall time the procedure took between
        two ticks (median, p99, max, in ms), the period (ms), how many ticks took longer than
        it, and the ticks counted. {} before two ticks."""
        import numpy as np

        work = np.frombuffer(self._work, dtype=float) if len(self._work) else np.zeros(0)
        if work.size == 0:
            return {}
        period = getattr(self, "period", 1.0 / self.rate)
        return {"period_ms": period * 1e3, "ticks": int(work.size),
                "tick_median_ms": float(np.median(work) * 1e3), "tick_p99_ms": float(np.percentile(work, 99) * 1e3),
                "tick_max_ms": float(work.max() * 1e3), "over_period": int(np.count_nonzero(work > period))}

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


def _set_rate(self, rate: float, min_fraction: float | None = None) -> None:
    """Pace a loop clock that waits on its sources at `rate` Hz from now on (a procedure
    whose loop runs slower than [rig] rate); `min_fraction`: of a period between two ticks
    at least (1.0 for a loop slower than its sources, which would otherwise tick at every
    new sample)."""
    if not rate > 0:
        raise ValueError(f"clock rate must be > 0 Hz, got {rate}")
    self.rate = float(rate)
    self.period = 1.0 / self.rate
    if min_fraction is not None:
        self.min_fraction = float(min_fraction)


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
        self.overruns = 0   # a tick is the physics step: never late, nothing skipped
        self.skipped = 0

    def now(self) -> float:
        return self.world.t

    def tick(self) -> None:
        self._tick_called()
        self.world.step()
        self._notify(self.world.t)
        self._tick_returns()

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
        self._tick_called()
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
        self._tick_returns()

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

    set_rate = _set_rate

    def tick(self) -> None:
        self._tick_called()
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
        self._tick_returns()


#: s of executor-polled wall time a loop in lockstep waits for a period's sample before it
#: answers the period without it (a source that stopped must not hold the world: its own
#: watchdog, on simulated time, has to see the clock go on to fire)
LATE_SAMPLE = 2.0


class SimTimeClock(_Listeners):
    """Simulated time from a simulator's /clock, in lockstep (`drivers.common.time_base.SimTime`).

    `tick()` answers the period the loop has just acted on (its commands are sent), so the
    world steps on; it answers each period the loop skips once that period's samples have
    come; and it returns at the first period at least `min_fraction` of a loop period after
    the last one whose samples have all come: every arm's measured_js (`sources`: `received`
    and `last_stamp()`) and every byte a load cell (`syncs`: `caught_up(t)`) had written by
    then. The world waits meanwhile, however long the procedure computes, so nothing a
    procedure does depends on how fast the machine is. A source silent for LATE_SAMPLE s of
    polled wall time is answered without (counted in `late`), and so is every period after
    until it sends again; a tick then returns after `max_fraction` loop periods of simulated
    time at the latest (counted in `overruns`): the silent stream's own watchdog, on the
    simulated clock that goes on, ends the run. `now()` is the simulated time (s).
    """

    def __init__(self, rate: float, sources, time_base, min_fraction: float = 0.75, max_fraction: float = 1.5,
                 polled=None) -> None:
        super().__init__()
        if not rate > 0:
            raise ValueError(f"clock rate must be > 0 Hz, got {rate}")
        self.rate = float(rate)
        self.period = 1.0 / self.rate
        self.time = time_base
        self.sources = list(sources)
        self.min_fraction = float(min_fraction)
        self.max_fraction = float(max_fraction)
        self._polled = polled or time.monotonic
        self._last: float | None = None
        self._seen = [s.received for s in self.sources]
        self.overruns = 0
        self.skipped = 0
        self.late = 0
        self._degraded = False  # a source stopped: periods are answered without waiting for it

    def add_source(self, source) -> None:
        self.sources.append(source)
        self._seen.append(source.received)

    def add_sync(self, device) -> None:
        """A device whose bytes the loop waits to have been read (`caught_up(t)`): a load
        cell (kept by the time base, which waits for it when free too)."""
        self.time.add_sync(device)

    set_rate = _set_rate

    def now(self) -> float:
        return self.time.now()

    def _complete(self, t: float, seen) -> bool:
        """Every source has a sample of time `t` or later (newer than `seen`) and every sync
        device has been read up to `t`."""
        return (all(s.received > n and s.last_stamp() >= t - 1e-9 for s, n in zip(self.sources, seen))
                and all(d.caught_up(t) for d in self.time.syncs))

    def tick(self) -> None:
        self._tick_called()
        tb = self.time
        since = tb.now() if self._last is None else self._last
        target = since + self.min_fraction * self.period
        deadline = since + self.max_fraction * self.period
        tb.hold()
        # the loop has acted on the newest period: the world may step on, up to the period
        # the loop acts on next without waiting for an answer
        answered = tb.answer(next_ns=int(round(target * 1e9)))
        seen = list(self._seen)
        waiting_since = self._polled()
        late = False
        with tb.changed:
            while True:
                t_ns = tb.now_ns() or 0
                t = t_ns * 1e-9
                if t_ns > answered:
                    if self._complete(t, seen if t >= target else [-1] * len(seen)):
                        self._degraded = False
                        if t >= target:
                            break
                        tb.answer(t_ns)  # a period the loop does not act on: its samples are in
                        answered, waiting_since = t_ns, self._polled()
                        continue
                    if self._degraded or self._polled() - waiting_since > LATE_SAMPLE:
                        self._degraded = True
                        # a source that stopped: answer without it, so that the clock goes on
                        # and its watchdog (on simulated time) can see it
                        late = True
                        if t >= deadline:
                            break
                        tb.answer(t_ns)
                        answered, waiting_since = t_ns, self._polled()
                        continue
                tb.check()
                tb.changed.wait(0.05)
        if late:
            self.late += 1
            self.overruns += 1
        self._last = t
        self._seen = [s.received for s in self.sources]
        self._notify(t)
        self._tick_returns()

    def sleep(self, duration: float) -> None:
        """Tick for `duration` seconds of simulated time (rounded to whole periods)."""
        for _ in range(int(round(duration * self.rate))):
            self.tick()
