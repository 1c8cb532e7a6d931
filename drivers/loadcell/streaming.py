"""The host side a serial and a CAN load cell share: commands, replies, samples, stale checks, counts.

The protocol is specified in `drivers/LOADCELL_PROTOCOL.md` and the sketch in
`drivers/firmware/loadcell/loadcell.ino` implements it on the Arduino. The load cell's
modules, bottom up: `protocol` (frames, payloads, CRC), `frame_parser` (a streaming parser
that resynchronises on garbage and counts what it rejects), `stream_tracking` (gaps,
out-of-order, device restarts; device micros() -> host seconds, with u32 wraparound and
crystal drift), `errors`, `force_calibration` (counts -> newtons from two known masses, plus
a tare offset), this module, the drivers `serial_driver` (`LoadCell`, given an open
pyserial-like port, implements `drivers.interfaces.ForceSensor`; `serial_port` opens it) and
`can` (`CanLoadCell`), and the fakes: `device_model` (the firmware's physics), the far end's
emulators `fake_firmware` (the sketch's behaviour on a pseudo-terminal, fed by a tension
source (N), with noise, drift, saturation, corrupt frames and unplugging),
`fake_firmware_process` (the same in a process of its own, for `rig sim`) and
`fake_can_firmware` (the CAN build on a python-can virtual bus), and the in-process twin `sim`.

Units: force in newtons (N, tension positive), time in seconds on the host clock unless
a name ends in `_us` (device microseconds), raw ADC values in counts.
"""

from __future__ import annotations

import abc

import math
import queue
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, replace
from typing import Callable

from drivers.interfaces import ForceSample
from drivers.loadcell.errors import LoadCellCommandError, LoadCellDisconnected, LoadCellError, LoadCellNotCalibrated
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.protocol import (ADC_NAMES, BAUDRATE, CMD_IDENTIFY, CMD_SET_RATE, CMD_START, CMD_STATUS, CMD_STOP,
                                       CMD_TARE, COMMAND_NAMES, COMMAND_TIMEOUT, ERROR_NAMES, PROTOCOL_VERSION, RATE_FMT,
                                       REPLY, T_ERROR, TARE_CMD_FMT, TARE_REPLY_FMT, Identity, RawSample, Status,
                                       decode_identity, decode_status)
from drivers.loadcell.stream_tracking import ClockMapper, SequenceTracker
from rig.faults import rate_of, silence_text, starved_text


# --------------------------------------------------------------------------- host driver

@dataclass
class LoadCellStats:
    """What the driver received and rejected since it started (events; `lost` in frames)."""

    frames_ok: int = 0
    samples: int = 0
    replies: int = 0
    crc_errors: int = 0
    truncated: int = 0
    bad_length: int = 0
    resyncs: int = 0
    bytes_discarded: int = 0
    gaps: int = 0
    lost: int = 0  # sequence numbers never received
    out_of_order: int = 0
    restarts: int = 0
    saturated: int = 0
    dropped: int = 0  # received but overwritten before anyone called samples()
    device_errors: int = 0  # error replies from the device

    def problems(self) -> int:
        return (self.crc_errors + self.truncated + self.bad_length + self.resyncs + self.lost
                + self.out_of_order + self.restarts + self.dropped)

    def table(self) -> str:
        return "\n".join(f"{k:>16} {v}" for k, v in asdict(self).items())


class _StreamingLoadCell(abc.ABC):
    """Sample buffering, staleness, calibration and commands shared by serial and CAN drivers."""

    def __init__(self, calibration: LoadCellCalibration | None, stale_timeout: float,
                 clock: Callable[[], float], on_sample: Callable[[ForceSample, float], None] | None,
                 buffer_size: int, name: str, time_base=None) -> None:
        from drivers.common.time_base import WallTime

        self.calibration = calibration
        #: the clock of the command and connect timeouts (`drivers.common.time_base`; `clock` stamps
        #: the samples): simulated time when the rig follows `rig sim --sim-time`
        self.time_base = time_base if time_base is not None else WallTime()
        #: clock() at which the reader last found the transport empty with everything before
        #: parsed: every byte written before that time has been taken (`caught_up`)
        self._caught_up = float("-inf")
        self.stale_timeout = stale_timeout
        self.clock = clock
        self.on_sample = on_sample
        self.name = name
        self._lock = threading.Lock()
        self._buffer: deque[ForceSample] = deque()
        self._buffer_size = buffer_size
        self._latest: ForceSample | None = None
        self._last_rx: float | None = None
        self._last_poll: float | None = None  # clock() when the reader last looked at the transport
        self._device_times: deque[float] = deque(maxlen=64)  # device s of the newest samples (their rate)
        self._streaming = False
        self._error: LoadCellError | None = None
        self._replies: queue.Queue[tuple[int, bytes]] = queue.Queue()
        self._cmd_lock = threading.Lock()
        self._stop = threading.Event()
        self._stats = LoadCellStats()
        self._seq = SequenceTracker(self._seq_bits)
        self._clockmap = ClockMapper()
        self.rate_hz = 0
        self.identity: Identity | None = None
        self._tare_pending = False
        if self.time_base.simulated:
            # from the first command on: the world must not run ahead of a starved reader
            # (its replies would come later than their timeout on the world's clock)
            self.time_base.add_sync(self)

    _seq_bits = 32
    #: the rig.toml key of `stale_timeout`, named by the stale line
    setting = "[loadcell] stale_timeout"
    connect_timeout = 2.5  # s, covers the Arduino bootloader after a DTR reset

    # ---- reader-thread side
    def _fail(self, error: LoadCellError) -> None:
        with self._lock:
            if self._error is None:
                self._error = error

    def _check_stale(self, now: float) -> None:
        if self._streaming and self._error is None and self._last_rx is not None:
            age = now - self._last_rx
            if age > self.stale_timeout:
                self._fail(LoadCellDisconnected(self._stale_line(age)))

    def _stale_line(self, age: float) -> str:
        """The one line of a cell silent for `age` s: how long, at what rate its samples had
        been coming (the device's own clock; the rate it was set to before two samples),
        the limit and its key, and that a starved process looks the same as a dead cable."""
        with self._lock:
            rate = rate_of(self._device_times) or float(self.rate_hz)
        return (f"load cell on {self.name}: {silence_text(age, rate, noun='sample')}, beyond the stale timeout "
                f"{self.stale_timeout * 1e3:.0f} ms ({self.setting}). "
                + starved_text(self.setting, "the cell is plugged in and powered (or `rig sim` runs)",
                               "check the cable and power"))

    def _on_raw_sample(self, s: RawSample, rx: float, elapsed_periods: float | None = None) -> bool:
        """Deliver one decoded sample; False if it was out of order (counted, not delivered)."""
        st = self._stats
        if not self._seq.accept(s.seq, elapsed_periods):
            return False
        t = self._clockmap.map(s.t_us, rx)
        device_t = self._clockmap._ext_us * 1e-6  # the unwrapped device time map() just took
        if self.time_base.simulated:
            # on simulated time the served firmware's micros() is the world's clock (`rig sim
            # --sim-time`): the sample's time itself. The mapping from this host's reading of
            # that clock would not do: the world runs ahead of a free process's clock
            t = device_t
        cal = self.calibration
        force = cal.newtons(s.counts) if cal is not None else math.nan
        sample = ForceSample(t=t, force=force, raw=s.counts, seq=s.seq)
        with self._lock:
            st.samples += 1
            if s.saturated:
                st.saturated += 1
            if len(self._buffer) >= self._buffer_size:
                self._buffer.popleft()
                st.dropped += 1
            self._buffer.append(sample)
            self._latest = sample
            self._last_rx = rx
            self._device_times.append(device_t)
        if self.on_sample is not None:
            self.on_sample(sample, rx)
        return True

    def _on_reply(self, ftype: int, payload: bytes) -> None:
        if ftype == CMD_TARE | REPLY and self._tare_pending and len(payload) == TARE_REPLY_FMT.size:
            # re-zero here, in the reader thread, so every sample decoded after the reply
            # (the firmware sends it before the next sample) reads against the new zero
            with self._lock:
                self._tare_pending = False
                if self.calibration is not None:
                    self.calibration = self.calibration.with_tare(TARE_REPLY_FMT.unpack(payload)[0])
        self._stats.replies += 1
        if ftype == T_ERROR:
            self._stats.device_errors += 1
        self._replies.put((ftype, payload))

    # ---- caller side
    def _raise_if_unusable(self) -> None:
        if self._error is not None:
            raise self._error
        if not self._streaming:
            raise LoadCellError(f"load cell on {self.name} is not streaming; call start()")
        self._check_stale(self._polled_now())
        if self._error is not None:
            raise self._error

    def _polled_now(self) -> float:
        """Now, as far as the reader thread has looked: a starved reader (the process busy)
        has not seen the samples waiting in the port, which must not count as silence."""
        now = self.clock()
        poll = self._last_poll
        return now if poll is None else min(now, poll)

    def caught_up(self, t: float) -> bool:
        """The reader has taken every byte the device had written by clock time `t` (it found
        the transport empty at `t` or later, after parsing what came before). A loop in
        lockstep with the device's simulator waits on it before reading the force of `t`."""
        return self._caught_up >= t or self._error is not None or self._stop.is_set()

    def stream_age(self) -> float:
        """Seconds since the last sample as of the reader's last look (inf before the first)."""
        rx = self._last_rx
        return float("inf") if rx is None else self._polled_now() - rx

    def read(self) -> ForceSample:
        """The newest sample (N, host seconds). Raises if disconnected, stale or uncalibrated."""
        with self._lock:
            latest = self._latest
        self._raise_if_unusable()
        if self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: no calibration loaded; run `rig loadcell-calibrate`")
        if latest is None:
            raise LoadCellDisconnected(f"load cell on {self.name}: no sample received yet")
        return latest

    def samples(self) -> list[ForceSample]:
        """Every sample since the last call, oldest first.

        Samples received before a disconnect are returned first; the error is raised on
        the next call that finds nothing new.
        """
        out = self.raw_samples()
        if out and self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: no calibration loaded; run `rig loadcell-calibrate`")
        return out

    def raw_samples(self) -> list[ForceSample]:
        """Like samples() but without a calibration (force is NaN when none is loaded)."""
        with self._lock:
            out = list(self._buffer)
            self._buffer.clear()
        if not out and (self._streaming or self._error is not None):
            self._raise_if_unusable()  # after stop(), nothing new is simply nothing
        return out

    def device_rate(self) -> float:
        """Hz at which the device converts, from its own sample times over its newest samples
        (0.0 before two): what the firmware streams, whatever delays this host's reading of
        them. The mean over their span, not the median interval: a served firmware that
        caught up with its world converts a burst of samples microseconds apart."""
        with self._lock:
            t = list(self._device_times)
        span = t[-1] - t[0] if len(t) >= 2 else 0.0
        return (len(t) - 1) / span if span > 0 else 0.0

    def stats(self) -> LoadCellStats:
        """A snapshot of the counters."""
        with self._lock:
            return replace(self._stats)

    def collect_counts(self, seconds: float) -> list[int]:
        """Raw counts of the samples converted during the next `seconds` (s)
        (`collect_samples`)."""
        return [s.raw for s in self.collect_samples(seconds)]

    def collect_samples(self, seconds: float) -> list:
        """The raw samples converted during the next `seconds` (s).

        Selected by their (mapped) conversion time, so a sample taken before the call but
        delivered late is not mixed in. The window is complete when a sample converted
        after its end has arrived (on a loaded host the last ones come tens of ms late, or
        hundreds), or at the latest a stale timeout after its end.
        """
        start = self.clock()
        end = start + seconds
        out: list = []
        while True:
            late = self.clock() >= end + max(0.02, self.stale_timeout)
            new = self.raw_samples()
            out.extend(s for s in new if start <= s.t < end)
            if late or any(s.t >= end for s in new):
                return out
            self.time_base.sleep(0.005)

    @abc.abstractmethod
    def _send(self, ctype: int, payload: bytes) -> None:
        """Put one command on the transport (a framed serial write, or a CAN frame)."""

    def close(self) -> None:
        """Stop streaming (if the device still answers) and the reader thread. Leaves the
        transport (port or bus) open: whoever opened it closes it."""
        if self._error is None and self._streaming:
            try:
                self.stop()
            except LoadCellError:
                pass
        self._stop.set()
        self._thread.join(timeout=1.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def command(self, ctype: int, payload: bytes = b"", timeout: float | None = None) -> bytes:
        """Send one command and return its reply payload (within `timeout` s, default
        COMMAND_TIMEOUT); raises LoadCellCommandError."""
        timeout = COMMAND_TIMEOUT if timeout is None else timeout
        with self._cmd_lock:
            if self._error is not None:
                raise self._error
            while not self._replies.empty():  # late replies to earlier timed-out commands
                self._replies.get_nowait()
            self._send(ctype, payload)
            tb = self.time_base
            end = tb.now() + timeout
            while True:
                tb.free()
                left = end - tb.now()
                if left <= 0:
                    if self._error is not None:
                        raise self._error
                    raise LoadCellCommandError(
                        f"load cell on {self.name}: no reply to {COMMAND_NAMES.get(ctype, hex(ctype))} "
                        f"within {timeout * 1e3:.0f} ms")
                try:
                    rtype, rpayload = self._replies.get(timeout=min(left, 0.02))
                except queue.Empty:
                    if self._error is not None:
                        raise self._error
                    continue
                if rtype == ctype | REPLY:
                    return rpayload
                if rtype == T_ERROR and len(rpayload) == 2 and rpayload[0] == ctype:
                    raise LoadCellCommandError(
                        f"load cell on {self.name}: {COMMAND_NAMES.get(ctype, hex(ctype))} refused: "
                        f"{ERROR_NAMES.get(rpayload[1], f'error {rpayload[1]:#04x}')}")
                # an error about a different (garbled) command, or a stray reply: keep waiting

    def identify(self, timeout: float = 0.5) -> Identity:
        ident = decode_identity(self.command(CMD_IDENTIFY, timeout=timeout))
        if ident.protocol != PROTOCOL_VERSION:
            raise LoadCellError(f"load cell on {self.name} speaks protocol {ident.protocol}, "
                                f"this driver speaks {PROTOCOL_VERSION}; update the firmware or the package")
        self.identity = ident
        return ident

    def status(self) -> Status:
        return decode_status(self.command(CMD_STATUS))

    def set_rate(self, rate_hz: int) -> int:
        """Sample rate (Hz); returns the rate the device took."""
        self.rate_hz = RATE_FMT.unpack(self.command(CMD_SET_RATE, RATE_FMT.pack(rate_hz)))[0]
        return self.rate_hz

    def start(self) -> None:
        self.command(CMD_START)
        with self._lock:
            self._last_rx = self.clock()  # the stale clock starts now
            self._streaming = True

    def stop(self) -> None:
        with self._lock:
            self._streaming = False
        self.command(CMD_STOP)

    def tare_counts(self, conversions: int = 64) -> int:
        """Ask the device for the mean of its next `conversions` readings (counts)."""
        if not 1 <= conversions <= 255:
            raise ValueError("conversions must be 1..255")
        # the averaging, plus a margin for a host under load (bench_hil with two CPU burners
        # and three cells: a reply came more than 0.5 s after the averaging ended)
        timeout = 1.5 + conversions / max(self.rate_hz, 1)
        mean, _n = TARE_REPLY_FMT.unpack(self.command(CMD_TARE, TARE_CMD_FMT.pack(conversions), timeout))
        return mean

    def tare(self, conversions: int = 64) -> None:
        """Zero the force at the present load (device-averaged over `conversions` samples).

        Samples converted after the device's tare reply read against the new zero; those
        already received keep the force they had.
        """
        if self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: tare needs a calibration; run `rig loadcell-calibrate`")
        self._tare_pending = True
        try:
            self.tare_counts(conversions)  # the reader thread applies the reply
        finally:
            self._tare_pending = False

    def _no_reply(self, exc: Exception) -> str:
        """What a device that never answers IDENTIFY asks the user to check, first the
        baud rate (a firmware at another rate answers nothing the parser can frame)."""
        baud = getattr(getattr(self, "port", None), "baudrate", None)
        at = f" at {baud} baud" if baud else ""
        return (f"load cell on {self.name}: no reply to IDENTIFY within {self.connect_timeout:g} s{at}; check "
                f"the baud rate ([loadcell] baudrate; the rig's firmware talks at {BAUDRATE}), that the board "
                "runs the rig's firmware (drivers/firmware/loadcell), the port and the cable")

    def _setup(self, rate_hz: int, start: bool) -> None:
        try:
            # an Uno/Nano resets when the port opens and its bootloader listens for ~1.5 s,
            # so the first IDENTIFYs may go unanswered
            tb = self.time_base
            deadline = tb.now() + self.connect_timeout
            while True:
                try:
                    self.identify(timeout=0.25)
                    break
                except LoadCellCommandError as exc:
                    if self._error is not None:
                        raise
                    if tb.now() > deadline:
                        raise LoadCellCommandError(self._no_reply(exc)) from None
            if self.identity is not None and rate_hz > self.identity.max_rate_hz:
                raise LoadCellError(
                    f"load cell on {self.name}: {rate_hz} Hz asked, the "
                    f"{ADC_NAMES.get(self.identity.adc, 'ADC')} firmware allows {self.identity.max_rate_hz} Hz")
            self.set_rate(rate_hz)
            if start:
                self.start()
        except BaseException:
            # the reader must be gone before the caller retries on the same port,
            # or two threads would split the replies between them
            self._stop.set()
            self._thread.join(timeout=1.0)
            raise
