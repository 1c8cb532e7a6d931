"""The one base class of device faults: a device stopped answering or answered nonsense.

A stale arm stream, a load cell whose cable came out, a pty that is not a load cell, a
mocap bridge that went quiet, an operator who never answered, a stream that never
arrived: each driver raises its own subclass of `DeviceFault` with one line naming the
device and what to check. The run engine (`rig.runs.run`) records such a run as aborted (the
arms it moved are held, the recording is closed with the line as its reason) and the
command prints the line and exits non-zero, without a traceback.

A stale stream's line (`silence_text`, `starved_text`) says how long the stream has been
silent, at what rate it had been coming, the rig.toml key of its limit, and that a starved
process looks the same as a stopped device: silence alone cannot tell them apart.
"""

from __future__ import annotations

import math


class DeviceFault(RuntimeError):
    """A device fault; str(fault) is one line for a person (device, what happened, what to check).

    `fields()`: the same fault for a program (the run engine records it in the run's stop
    record and result, `rig runs RUN` reads it): `arm`, its operating `state`, the `joint`
    (1-3) and the `limit` it concerns, where the fault knows them."""

    arm: str | None = None
    state: str | None = None
    joint: int | None = None
    limit: str | None = None

    def fields(self) -> dict:
        return {k: getattr(self, k) for k in ("arm", "state", "joint", "limit") if getattr(self, k) is not None}


def rate_of(times) -> float:
    """Hz at which a stream had been coming: 1 / the median positive interval of `times`
    (s, oldest first; the header stamps of its newest messages), 0.0 with fewer than two."""
    ts = list(times)
    gaps = sorted(b - a for a, b in zip(ts, ts[1:]) if b > a)
    if not gaps:
        return 0.0
    n = len(gaps)
    mid = gaps[n // 2] if n % 2 else 0.5 * (gaps[n // 2 - 1] + gaps[n // 2])
    return 1.0 / mid


def silence_text(age: float, rate_hz: float | None, noun: str = "message", seconds: bool = False) -> str:
    """How late a stream is, for a stale stream's line: "no message for 412 ms (41 periods
    of the 100 Hz it had been coming at)". age: s since its last message (inf: none ever
    came); rate_hz: the rate it had been coming at (0 or None: unknown, fewer than two
    messages); seconds: the age in s with three decimals instead of ms."""
    if not math.isfinite(age):
        return f"no {noun} ever received"
    text = f"no {noun} for {age:.3f} s" if seconds else f"no {noun} for {age * 1e3:.0f} ms"
    if rate_hz:
        return text + f" ({age * rate_hz:.0f} periods of the {rate_hz:.4g} Hz it had been coming at)"
    return text + f" (its rate unknown: fewer than two {noun}s before)"


def starved_text(setting: str, running: str, otherwise: str) -> str:
    """The end of every stale stream's line: a process held off the CPU cannot be told from
    a stopped device by the silence alone, so the line names both and what to do for each.
    setting: the rig.toml key of the limit ("[arms.PSM1] watchdog"); running: the device
    or its publisher, as a clause ("the dVRK console (or `rig sim`) runs on
    ROS_DOMAIN_ID=0"); otherwise: what to do if it does not ("start it there")."""
    return (f"A starved process (this one or the publisher, held off the CPU) looks the same as a stopped "
            f"device: if {running}, the machine is too busy for this stream (free a CPU or raise {setting}); "
            f"if not, {otherwise}")
