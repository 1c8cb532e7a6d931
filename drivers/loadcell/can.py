"""Load cell on CAN: the same commands and samples as on serial, on documented CAN ids.

See `drivers/LOADCELL_PROTOCOL.md`, "CAN variant". `CanLoadCell` takes an open python-can
bus (any interface: socketcan, pcan, ... or `virtual` for tests) and implements
`drivers.interfaces.ForceSensor`; its far end, the firmware on a python-can virtual bus
channel, is `drivers.loadcell.fake_can_firmware.FakeCanLoadCellFirmware`.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Callable

import can

from drivers.interfaces import ForceSample
from drivers.loadcell.errors import LoadCellDisconnected
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.protocol import SAMPLE_SATURATED, RawSample
from drivers.loadcell.streaming import _StreamingLoadCell

DEFAULT_BASE_ID = 0x300
SAMPLE_OFFSET, COMMAND_OFFSET, REPLY_OFFSET = 0, 1, 2
INT24_MIN, INT24_MAX = -(1 << 23), (1 << 23) - 1
_TAIL = struct.Struct("<I")


def encode_can_sample(s: RawSample) -> bytes:
    """8 bytes: seq mod 128 | saturated << 7, counts i24 LE, t_us u32 LE."""
    counts, flags = s.counts, s.flags
    if not INT24_MIN <= counts <= INT24_MAX:
        counts, flags = max(INT24_MIN, min(INT24_MAX, counts)), flags | SAMPLE_SATURATED
    head = (s.seq & 0x7F) | (0x80 if flags & SAMPLE_SATURATED else 0)
    return bytes((head,)) + (counts & 0xFFFFFF).to_bytes(3, "little") + _TAIL.pack(s.t_us & 0xFFFFFFFF)


def decode_can_sample(data: bytes) -> RawSample:
    """The inverse of encode_can_sample; seq is the 7-bit value as sent."""
    if len(data) != 8:
        raise ValueError(f"CAN sample needs 8 bytes, got {len(data)}")
    counts = int.from_bytes(data[1:4], "little", signed=True)
    return RawSample(seq=data[0] & 0x7F, t_us=_TAIL.unpack(data[4:8])[0], counts=counts,
                     flags=SAMPLE_SATURATED if data[0] & 0x80 else 0)


class CanLoadCell(_StreamingLoadCell):
    """Host driver for the CAN load cell (implements ForceSensor).

    `bus` is an open python-can bus; the driver never shuts it down. Ids are
    `base_id` + 0 (samples), + 1 (commands), + 2 (replies). CAN has no end-of-file, so a
    dead cable or a powered-off cell shows as no sample for `stale_timeout` (s), or as a
    CanError from the bus. Other arguments as for `drivers.loadcell.serial_driver.LoadCell`.
    """

    _seq_bits = 7

    def __init__(self, bus: can.BusABC, calibration: LoadCellCalibration | None = None, *,
                 base_id: int = DEFAULT_BASE_ID, rate_hz: int = 500, stale_timeout: float = 0.05,
                 clock: Callable[[], float] = time.monotonic,
                 on_sample: Callable[[ForceSample, float], None] | None = None,
                 buffer_size: int = 65536, start: bool = True) -> None:
        super().__init__(calibration, stale_timeout, clock, on_sample, buffer_size,
                         name=f"CAN {getattr(bus, 'channel_info', bus)} id {base_id:#05x}")
        self.bus = bus
        self.base_id = base_id
        self._last_t_us: int | None = None
        self._thread = threading.Thread(target=self._reader, name="loadcell-can", daemon=True)
        self._thread.start()
        self._setup(rate_hz, start)

    def _send(self, ctype: int, payload: bytes) -> None:
        msg = can.Message(arbitration_id=self.base_id + COMMAND_OFFSET, data=bytes((ctype,)) + payload,
                          is_extended_id=False)
        try:
            self.bus.send(msg, timeout=0.05)
        except can.CanError as exc:
            err = LoadCellDisconnected(f"load cell on {self.name}: send failed: {exc}")
            self._fail(err)
            raise err from exc

    def _elapsed_periods(self, t_us: int) -> float | None:
        if self._last_t_us is None or self.rate_hz <= 0:
            return None
        d = (t_us - self._last_t_us) & 0xFFFFFFFF
        if d >= 1 << 31:
            d -= 1 << 32  # older than the last sample
        return d * self.rate_hz * 1e-6

    def _reader(self) -> None:
        sample_id = self.base_id + SAMPLE_OFFSET
        reply_id = self.base_id + REPLY_OFFSET
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.005)
            except (can.CanError, OSError, ValueError) as exc:
                self._fail(LoadCellDisconnected(f"load cell on {self.name}: bus failed: {exc}"))
                return
            rx = self._last_poll = self.clock()
            if msg is not None and not msg.is_error_frame and not msg.is_remote_frame:
                if msg.arbitration_id == sample_id:
                    if msg.dlc == 8:
                        s = decode_can_sample(bytes(msg.data))
                        with self._lock:
                            self._stats.frames_ok += 1
                        if self._on_raw_sample(s, rx, self._elapsed_periods(s.t_us)):
                            self._last_t_us = s.t_us
                    else:
                        with self._lock:
                            self._stats.bad_length += 1
                elif msg.arbitration_id == reply_id and msg.dlc >= 1:
                    with self._lock:
                        self._stats.frames_ok += 1
                    self._on_reply(msg.data[0], bytes(msg.data[1:msg.dlc]))
                with self._lock:
                    sq, st = self._seq, self._stats
                    st.gaps, st.lost, st.out_of_order, st.restarts = sq.gaps, sq.lost, sq.out_of_order, sq.restarts
            self._check_stale(self.clock())


__all__ = ["CanLoadCell", "encode_can_sample", "decode_can_sample", "DEFAULT_BASE_ID"]
