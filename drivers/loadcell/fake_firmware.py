"""The Arduino firmware emulated on a pseudo-terminal, byte for byte."""

from __future__ import annotations

import os
import random
import select
import threading
import time
import tty
from collections import deque
from typing import Callable

from drivers.loadcell.device_model import LoadCellDeviceModel
from drivers.loadcell.frame_parser import FrameParser
from drivers.loadcell.protocol import BAUDRATE, FRAME_OVERHEAD, RawSample, encode_frame, sample_frame

#: Linux's TCGETS2 ioctl (struct termios2: the line's speed in c_ispeed, c_ospeed)
_TCGETS2 = 0x802C542A


def line_baudrate(fd: int) -> int | None:
    """The baud rate a terminal's line is set to (a pty keeps what the host's pyserial set),
    or None where it cannot be read."""
    import array
    import fcntl
    import struct

    try:
        buf = array.array("i", [0] * 16)
        fcntl.ioctl(fd, _TCGETS2, buf)
    except OSError:
        return None
    return struct.unpack_from("I", buf.tobytes(), 40)[0] or None


class FakeLoadCellFirmware:
    """The sketch, emulated on a pseudo-terminal: open `port_path` with `serial.Serial`.

    Runs in its own thread once started (`start()` or `with`). The model (`.model`) holds
    the physics: `tension_source()` (N) and `clock()` (s) feed it; `noise` (N rms),
    `drift` (N/s) and `adc_limits` (counts) are settable at any time. Faults:
    `corrupt_probability` (each sample frame gets one bit flipped with that probability),
    `inject(kind, count)` for the next `count` sample frames with kind in
    {"crc", "truncate", "garbage", "skip", "swap"}, and `unplug()` (closes the pty).
    Like the Arduino's 64-byte serial buffer, a frame that does not fit in the output
    backlog is dropped (its sequence number is used, so the host sees a gap).
    `write_times` (if `record_write_times`) maps seq -> time.monotonic() right after the
    frame was written to the pty: a side channel for latency benchmarks.
    """

    TX_BACKLOG = 64  # bytes, the Arduino core's TX ring buffer

    def __init__(self, tension_source: Callable[[], float], clock: Callable[[], float] | None = None, *,
                 record_write_times: bool = False, seed: int = 0, baudrate: int = BAUDRATE, **model_kwargs) -> None:
        self.model = LoadCellDeviceModel(tension_source, clock, seed=seed, **model_kwargs)
        self.rng = random.Random(seed + 1)
        self.corrupt_probability = 0.0
        self._inject: deque[str] = deque()
        self._swap_held: bytes | None = None
        self.injected: dict[str, int] = {}
        self.frames_sent = 0
        self.record_write_times = record_write_times
        self.write_times: dict[int, float] = {}
        self.sample_times: dict[int, float] = {}  # seq -> clock() at conversion (truth for time mapping)
        #: the sketch's LOADCELL_BAUD: a host that opens the pty at another rate (its termios
        #: speed, which a pty keeps) is answered by nothing, as a board at another rate
        self.baudrate = baudrate
        self.misframed = 0  # bytes received at the wrong rate
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: a byte pipe like a USB CDC port
        os.set_blocking(self._master, False)
        self.port_path = os.ttyname(self._slave)
        self._tx = bytearray()
        self._rx_last = 0.0
        self._parser = FrameParser(on_reject=self._on_reject)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fd_lock = threading.Lock()
        self.unplugged = False
        self._next_t: float | None = None  # model time of the next conversion (`pump`)

    # settable faults, forwarded to the model for convenience
    noise = property(lambda self: self.model.noise, lambda self, v: setattr(self.model, "noise", v))
    drift = property(lambda self: self.model.drift, lambda self, v: setattr(self.model, "drift", v))
    adc_limits = property(lambda self: self.model.adc_limits,
                          lambda self, v: setattr(self.model, "adc_limits", v))

    def inject(self, kind: str, count: int = 1) -> None:
        if kind not in ("crc", "truncate", "garbage", "skip", "swap"):
            raise ValueError(f"unknown fault kind {kind!r}")
        self._inject.extend([kind] * count)

    def start(self) -> "FakeLoadCellFirmware":
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="fake-loadcell", daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> "FakeLoadCellFirmware":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _on_reject(self, kind: str, ftype: int) -> None:
        for rtype, payload in self.model.reject(kind, ftype):
            self._queue(encode_frame(rtype, payload), is_sample=False)

    def _queue(self, frame: bytes, is_sample: bool) -> bool:
        if is_sample and len(self._tx) + len(frame) > self.TX_BACKLOG:
            self.model.tx_dropped += 1
            return False
        self._tx += frame
        return True

    def _flush(self) -> None:
        if not self._tx:
            return
        try:
            n = os.write(self._master, self._tx)
        except BlockingIOError:
            return
        del self._tx[:n]

    def _fault(self, frame: bytes) -> bytes:
        kind = self._inject.popleft() if self._inject else None
        if kind == "swap" and self._swap_held is not None:
            self._inject.appendleft(kind)  # one swap at a time: apply it after this pair
            kind = None
        if kind is None and self.corrupt_probability > 0 and self.rng.random() < self.corrupt_probability:
            kind = "crc"
        if kind is None:
            return frame
        self.injected[kind] = self.injected.get(kind, 0) + 1
        if kind == "crc":
            b = bytearray(frame)
            b[4 + self.rng.randrange(len(frame) - FRAME_OVERHEAD)] ^= 1 << self.rng.randrange(8)
            return bytes(b)
        if kind == "truncate":
            return frame[:self.rng.randrange(5, len(frame) - 1)]
        if kind == "garbage":
            # garbage that cannot contain a sync pattern, so the count is exact
            return bytes(self.rng.choice([0x00, 0x11, 0xFF, 0x5A, 0x42]) for _ in range(7)) + frame
        if kind == "skip":
            return b""
        # swap: hold this frame back and send it right after the next one
        self._swap_held = frame
        return b""

    def _send_sample(self, s: RawSample) -> None:
        frame = sample_frame(s)
        if len(self._tx) + len(frame) > self.TX_BACKLOG:
            self.model.tx_dropped += 1  # dropped before any fault is spent on it
            return
        frame = self._fault(frame)
        n = 1
        if frame and self._swap_held is not None:
            frame, self._swap_held, n = frame + self._swap_held, None, 2
        if frame and self._queue(frame, is_sample=True):
            self.frames_sent += n
            self._flush()
            if self.record_write_times:
                self.write_times[s.seq] = time.monotonic()

    def _receive(self, now: float) -> None:
        """Take the command bytes that came (non-blocking) and queue the replies."""
        m = self.model
        try:
            data = os.read(self._master, 256)
        except BlockingIOError:
            data = b""
        if data:
            self._rx_last = now
            baud = line_baudrate(self._slave)
            if baud is not None and baud != self.baudrate:
                # the host's UART at another rate: each byte it sends is sampled at the
                # sketch's rate and comes out as other bits (and framing errors); what the
                # sketch would answer never comes, as on the board
                data = bytes(self.rng.getrandbits(8) for _ in data)
                self.misframed += len(data)
            for f in self._parser.feed(data):
                for rtype, payload in m.handle(f.type, f.payload):
                    self._queue(encode_frame(rtype, payload), is_sample=False)
        elif self._parser.pending and now - self._rx_last > 0.05:
            self._parser.flush()  # a command that stopped half-way (reported via _on_reject)

    def _convert(self) -> None:
        """One conversion period of the sketch's loop: the sample and any tare reply."""
        m = self.model
        sample, replies = m.tick()
        for rtype, payload in replies:
            self._queue(encode_frame(rtype, payload), is_sample=False)
        if sample is not None:
            if self.record_write_times:
                self.sample_times[sample.seq] = m.clock()
            self._send_sample(sample)

    def _run(self) -> None:
        m = self.model
        next_t = time.monotonic()
        while not self._stop.is_set():
            wait = max(0.0, next_t - time.monotonic())
            try:
                readable, _, _ = select.select([self._master], [], [], wait)
                self._receive(time.monotonic()) if readable else self._receive_idle(time.monotonic())
                now = time.monotonic()
                if now >= next_t:
                    self._convert()
                    next_t += 1.0 / m.rate_hz
                    if now - next_t > 0.1:  # stalled far behind (debugger, suspend): do not burst
                        next_t = now
                self._flush()
            except OSError:
                if self._stop.is_set():
                    return
                # EIO: nobody holds the slave end any more; keep running like a device whose
                # USB host went away
                time.sleep(0.01)

    def _receive_idle(self, now: float) -> None:
        if self._parser.pending and now - self._rx_last > 0.05:
            self._parser.flush()

    def pump(self) -> None:
        """Run the sketch's loop up to the model's `clock()`, without a thread: the commands
        that came are answered and every conversion due is sent. For a firmware stepped by
        its host's loop on simulated time (`rig sim --sim-time`), where the samples must
        follow the world's clock, not the wall's: call it every servo period."""
        if self.unplugged:
            return
        m = self.model
        now = m.clock()
        if self._next_t is None:
            self._next_t = now
        try:
            self._receive(now)
            while now >= self._next_t:
                self._convert()
                self._next_t += 1.0 / m.rate_hz
            self._flush()
        except OSError:
            pass  # EIO: the host closed its end; a device keeps running without it

    def unplug(self) -> None:
        """Pull the USB cable: stop the firmware and close both ends of the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        with self._fd_lock:
            if not self.unplugged:
                self.unplugged = True
                for fd in (self._master, self._slave):
                    try:
                        os.close(fd)
                    except OSError:
                        pass

    close = unplug
