"""Sample sequence numbers (drops, repeats) and the device clock mapped onto the host's."""

from __future__ import annotations

import math

from drivers.common.clock_offset import BlockMinima, envelope_line


class SequenceTracker:
    """Checks sample sequence numbers: gaps (frames lost), out-of-order, device restarts.

    `bits` is the width of the sequence field (32 on serial, 7 on CAN). With a short field,
    pass `elapsed_periods` (device time since the last accepted sample / sample period) so
    a gap longer than the field's range is still counted right.
    An out-of-order (older or repeated) frame is rejected; eight consecutive frames that
    are consecutive among themselves but behind the last accepted one mean the device
    restarted, and the tracker follows it.
    """

    RESTART_RUN = 8

    def __init__(self, bits: int = 32) -> None:
        self.mod = 1 << bits
        self.last: int | None = None
        self.gaps = 0
        self.lost = 0
        self.out_of_order = 0
        self.restarts = 0
        self._behind_last: int | None = None
        self._behind_run = 0

    def reset(self) -> None:
        self.last = None
        self._behind_last, self._behind_run = None, 0

    def accept(self, seq: int, elapsed_periods: float | None = None) -> bool:
        """True if the sample is new and in order (then it is the newest)."""
        if self.last is None:
            self.last = seq
            return True
        diff = (seq - self.last) % self.mod
        if elapsed_periods is not None:
            # unfold the short counter with the device clock: the nearest whole wrap count
            diff += self.mod * round((elapsed_periods - diff) / self.mod)
            forward = diff > 0
        else:
            forward = 0 < diff < self.mod // 2
        if forward:
            if diff > 1:
                self.gaps += 1
                self.lost += diff - 1
            self.last = seq
            self._behind_last, self._behind_run = None, 0
            return True
        self.out_of_order += 1
        if self._behind_last is not None and (seq - self._behind_last) % self.mod == 1:
            self._behind_run += 1
        else:
            self._behind_run = 1
        self._behind_last = seq
        if self._behind_run >= self.RESTART_RUN:
            # the run was counted as out-of-order one by one; it was a restart instead
            self.out_of_order -= self._behind_run
            self.restarts += 1
            self.last = seq
            self._behind_last, self._behind_run = None, 0
            return True
        return False


class ClockMapper:
    """Maps device micros() (u32, wraps every 71.6 min) to host seconds.

    The serial link only ever delays a frame, so host_rx - device_time is the clock offset
    plus a non-negative delay; its minimum over a block of samples is close to the offset.
    A line through the last `blocks` block minima follows the Arduino's crystal drift
    (a ceramic resonator is good to ~0.1-0.5 %, i.e. up to 5 ms/s).
    Call `map` only for accepted (in-order) samples.
    """

    def __init__(self, block_s: float = 0.5, blocks: int = 16) -> None:
        self.block_s = block_s
        self._minima = BlockMinima(block_s, blocks)
        self._last_us: int | None = None
        self._ext_us = 0
        self._global_min = math.inf
        self._last_t = -math.inf

    def device_seconds(self, t_us: int) -> float:
        """Unwrapped device time (s) since the first sample's micros() epoch."""
        if self._last_us is None:
            self._ext_us = t_us
        else:
            self._ext_us += (t_us - self._last_us) & 0xFFFFFFFF
        self._last_us = t_us
        return self._ext_us * 1e-6

    def map(self, t_us: int, host_rx: float) -> float:
        dev = self.device_seconds(t_us)
        d = host_rx - dev
        self._minima.add(dev, d)
        self._global_min = min(self._global_min, d)
        offset = self.offset(dev)
        if self._minima.current is not None:
            offset = min(offset, self._minima.current[1])
        # never after its arrival; never before the previous sample (a new fit may step back)
        t = max(min(dev + offset, host_rx), self._last_t)
        self._last_t = t
        return t

    def offset(self, dev: float) -> float:
        """Estimated host - device clock offset (s) at device time `dev` (s)."""
        pts = self._minima.closed
        if len(pts) < 2:
            return self._global_min
        return envelope_line(pts, dev)
