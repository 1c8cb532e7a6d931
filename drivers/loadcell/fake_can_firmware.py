"""The load cell's firmware, CAN build, emulated: the far end of `drivers.loadcell.can.CanLoadCell`.

`FakeCanLoadCellFirmware` runs on a python-can virtual bus channel, with the same physics as
the serial fake (`drivers.loadcell.device_model.LoadCellDeviceModel`) and the frames of
`drivers/LOADCELL_PROTOCOL.md`, "CAN variant" (encoded by `drivers.loadcell.can`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

import can

from drivers.loadcell.can import COMMAND_OFFSET, DEFAULT_BASE_ID, REPLY_OFFSET, SAMPLE_OFFSET, encode_can_sample
from drivers.loadcell.device_model import LoadCellDeviceModel
from drivers.loadcell.protocol import ERR_BAD_LENGTH, ERROR_FMT, T_ERROR, RawSample


class FakeCanLoadCellFirmware:
    """The firmware's CAN build on a python-can virtual bus channel.

    `tension_source()` (N) and `clock()` (s) feed `LoadCellDeviceModel` (its keyword
    arguments: noise, drift, adc_limits, gain, ...). Faults: `inject(kind, count)` with kind
    in {"skip", "swap"} for the next sample messages (CAN frames arrive whole or not at
    all, so there is no CRC fault to inject), and `unplug()` (the cell goes silent and its
    bus end is shut down).
    """

    def __init__(self, tension_source: Callable[[], float], clock: Callable[[], float] | None = None, *,
                 channel: str = "loadcell", base_id: int = DEFAULT_BASE_ID, seed: int = 0,
                 record_write_times: bool = False, **model_kwargs) -> None:
        self.model = LoadCellDeviceModel(tension_source, clock, seed=seed, **model_kwargs)
        self.channel = channel
        self.base_id = base_id
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._inject: deque[str] = deque()
        self._held: can.Message | None = None
        self.injected: dict[str, int] = {}
        self.frames_sent = 0
        self.record_write_times = record_write_times
        self.write_times: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.unplugged = False

    noise = property(lambda self: self.model.noise, lambda self, v: setattr(self.model, "noise", v))
    drift = property(lambda self: self.model.drift, lambda self, v: setattr(self.model, "drift", v))

    def inject(self, kind: str, count: int = 1) -> None:
        if kind not in ("skip", "swap"):
            raise ValueError(f"unknown CAN fault kind {kind!r}")
        self._inject.extend([kind] * count)

    def start(self) -> "FakeCanLoadCellFirmware":
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="fake-loadcell-can", daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> "FakeCanLoadCellFirmware":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.unplug()

    def _reply(self, rtype: int, payload: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=self.base_id + REPLY_OFFSET, data=bytes((rtype,)) + payload,
                                  is_extended_id=False))

    def _send_sample(self, s: RawSample) -> None:
        msg = can.Message(arbitration_id=self.base_id + SAMPLE_OFFSET, data=encode_can_sample(s),
                          is_extended_id=False)
        kind = self._inject.popleft() if self._inject else None
        if kind is not None:
            self.injected[kind] = self.injected.get(kind, 0) + 1
        if kind == "skip":
            return
        if kind == "swap" and self._held is None:
            self._held = msg
            return
        self.bus.send(msg)
        self.frames_sent += 1
        if self.record_write_times:
            self.write_times[s.seq] = time.monotonic()
        if self._held is not None:
            self.bus.send(self._held)
            self.frames_sent += 1
            self._held = None

    def _run(self) -> None:
        m = self.model
        cmd_id = self.base_id + COMMAND_OFFSET
        next_t = time.monotonic()
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=max(0.0, next_t - time.monotonic()))
            if msg is not None and msg.arbitration_id == cmd_id and not msg.is_remote_frame:
                if msg.dlc == 0:
                    m.rx_errors += 1
                    self._reply(T_ERROR, ERROR_FMT.pack(0, ERR_BAD_LENGTH))
                else:
                    for rtype, payload in m.handle(msg.data[0], bytes(msg.data[1:msg.dlc])):
                        self._reply(rtype, payload)
            now = time.monotonic()
            if now >= next_t:
                sample, replies = m.tick()
                for rtype, payload in replies:
                    self._reply(rtype, payload)
                if sample is not None:
                    self._send_sample(sample)
                next_t += 1.0 / m.rate_hz
                if now - next_t > 0.1:
                    next_t = now

    def unplug(self) -> None:
        """Power the cell off: no more frames, and its end of the bus is shut down."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if not self.unplugged:
            self.unplugged = True
            self.bus.shutdown()

    close = unplug
